"""drape.geometry.queries.candidate_joints: the joints DeePSD may skin a garment vertex to."""

import numpy as np

from drape.assets.body import load_body
from drape.assets.outfits import generate_outfit
from drape.geometry.queries import candidate_joints, loose_points, nearest_vertex_weights


def _brute_force(points, body_vertices, body_weights, influences, margin, relative_margin):
    """The same rule by a full distance matrix over every body vertex (no k-d tree, no neighbour cap)."""
    d = np.linalg.norm(points[:, None] - body_vertices[None], axis=2)  # (P, M)
    d0 = d.min(axis=1, keepdims=True)
    near = d <= d0 + np.maximum(margin, relative_margin * d0)
    avg = near.astype(np.float64) @ body_weights
    mask = np.zeros(avg.shape, dtype=bool)
    for i, row in enumerate(avg):
        top = np.argsort(-row, kind="stable")[:influences]
        mask[i, top] = row[top] > 1e-4 * near[i].sum()
    return mask


def test_matches_a_brute_force_reading_of_the_rule():
    rng = np.random.default_rng(0)
    # a synthetic "body": two blobs of vertices, weights on joints 0-2 and 3-5
    verts = np.concatenate([rng.normal([0, 0, 0], 0.05, (300, 3)), rng.normal([0.3, 0, 0], 0.05, (300, 3))])
    weights = np.zeros((600, 24))
    weights[:300, :3] = rng.dirichlet([1, 1, 1], 300)
    weights[300:, 3:6] = rng.dirichlet([1, 1, 1], 300)
    points = rng.uniform([-0.2, -0.2, -0.2], [0.5, 0.2, 0.2], (200, 3))
    got = candidate_joints(points, verts, weights, influences=4, neighbours=600, stride=1)
    want = _brute_force(points, verts, weights, 4, 0.03, 0.5)
    np.testing.assert_array_equal(got, want)
    assert got.sum(axis=1).max() <= 4 and got.sum(axis=1).min() >= 1
    # a point halfway between the blobs sees both; a point inside one sees only its joints
    mid, inside = candidate_joints(np.array([[0.15, 0, 0], [0.0, 0, 0]]), verts, weights, influences=6,
                                   neighbours=600, stride=1)
    assert mid[:3].any() and mid[3:6].any()
    assert inside[:3].any() and not inside[3:].any()


def test_on_the_body_the_skin_s_joints_between_the_legs_both_legs():
    body = load_body("neutral")
    names = body.joint_names
    # points on the skin: their nearest body vertex's largest joint is always a candidate
    idx = np.random.default_rng(1).choice(len(body.vertices), 300, replace=False)
    mask = candidate_joints(body.vertices[idx], body.vertices, body.weights)
    assert mask[np.arange(300), body.weights[idx].argmax(axis=1)].all()
    assert mask.sum(axis=1).max() <= 4
    # a skirt's hem between the knees: both legs' joints, no arm or spine joint
    knees = body.joints[[names.index("left_knee"), names.index("right_knee")]]
    hem = knees.mean(axis=0) + [0, 0.05, 0]
    joints = {names[j] for j in np.flatnonzero(candidate_joints(hem[None], body.vertices, body.weights)[0])}
    assert {"left_hip", "right_hip"} <= joints or {"left_knee", "right_knee"} <= joints, joints
    assert not any("shoulder" in j or "elbow" in j or "spine" in j for j in joints), joints


def test_lowest_common_ancestor_against_walking_up_the_chains():
    from drape.geometry.queries import lowest_common_ancestor

    parents = load_body("neutral").parents
    rng = np.random.default_rng(2)
    joints = rng.integers(0, 24, (200, 3))
    valid = np.ones((200, 3), dtype=bool)
    valid[:50, 2] = False

    def ancestors(j):
        out = [j]
        while parents[out[-1]] >= 0:
            out.append(int(parents[out[-1]]))
        return out

    got = lowest_common_ancestor(parents, joints, valid)
    for row, v, g in zip(joints, valid, got, strict=True):
        chains = [ancestors(int(j)) for j in row[v]]
        want = next(a for a in chains[0] if all(a in c for c in chains[1:]))
        assert g == want


def test_loose_cloth_between_the_legs_may_follow_the_pelvis():
    body = load_body("neutral")
    names = body.joint_names
    knees = body.joints[[names.index("left_knee"), names.index("right_knee")]]
    hem = (knees.mean(axis=0) + [0, -0.1, 0.0])[None]  # a long skirt's hem between the shins
    tight = candidate_joints(hem, body.vertices, body.weights, parents=body.parents)
    loose = candidate_joints(hem, body.vertices, body.weights, parents=body.parents, loose_beyond=0.02)
    assert not tight[0, names.index("pelvis")]
    assert loose[0, names.index("pelvis")] and loose.sum() <= 4
    # near the skin nothing changes
    on_skin = body.vertices[::500]
    np.testing.assert_array_equal(candidate_joints(on_skin, body.vertices, body.weights, parents=body.parents,
                                                   loose_beyond=0.02),
                                  candidate_joints(on_skin, body.vertices, body.weights))


def test_loose_ancestor_prior_moves_a_share_onto_the_candidates_common_ancestor():
    from drape.training.deepsd_data import candidate_prior, loose_ancestor_prior

    body = load_body("neutral")
    o = generate_outfit("dress", vertices=1500, seed=3, body="neutral")
    mask = candidate_joints(o.vertices, body.vertices, body.weights, parents=body.parents, loose_beyond=0.03)
    prior = candidate_prior(nearest_vertex_weights(o.vertices, body.vertices, body.weights), mask)
    loose = np.linalg.norm(o.vertices[:, None] - body.vertices[None, ::4], axis=2).min(1) > 0.03
    np.testing.assert_array_equal(loose_points(o.vertices, body.vertices, 0.03), loose)  # the rule, brute force
    # candidate_joints applies the same rule: only loose rows gain a joint over the plain candidates
    changed = (mask != candidate_joints(o.vertices, body.vertices, body.weights)).any(axis=1)
    assert changed.any() and not (changed & ~loose).any()
    out = loose_ancestor_prior(prior, mask, loose, body.parents, 0.5)
    assert loose.any() and (~loose).any()
    np.testing.assert_array_equal(out[~loose], prior[~loose])
    np.testing.assert_allclose(out.sum(1), 1.0, atol=1e-5)
    assert not (out[~mask] > 0).any()  # the ancestor is one of the candidates: nothing leaves the mask
    added = out[loose] - 0.5 * prior[loose]  # (L, K): share 0.5 on one joint per loose row
    assert (np.abs(added).sum(1) > 0.5 - 1e-5).all() and ((added > 1e-6).sum(1) == 1).all()
    ancestor = added.argmax(1)

    def chain(j):  # j and its ancestors
        out = {int(j)}
        while body.parents[j] >= 0:
            j = body.parents[j]
            out.add(int(j))
        return out
    for a, row in zip(ancestor, mask[loose], strict=True):
        assert row[a] and all(a in chain(j) for j in np.flatnonzero(row))
    # between the legs below mid-thigh the ancestor is the pelvis, which the skin prior left at ~0
    thigh = 0.5 * (body.joints[1, 1] + body.joints[4, 1])
    low = o.vertices[loose, 1] < thigh
    assert (ancestor[low] == 0).any() and prior[loose][low & (ancestor == 0), 0].mean() < 0.1
    np.testing.assert_array_equal(loose_ancestor_prior(prior, mask, np.zeros(len(prior), bool), body.parents, 0.5),
                                  prior)
