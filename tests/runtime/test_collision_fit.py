"""The collision fit of the served rig: pushed targets against an independent exact distance, a rig with nothing
to push left as it is, fewer vertices inside the body on clips the fit never saw, and the engine serving it."""

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.mesh import vertex_normals
from drape.geometry.queries import MeshDistance
from drape.runtime.collision_fit import (
    EPS,
    PROCEDURAL_SEEDS,
    collision_fit,
    fit_poses,
    pushed_targets,
    served_rig,
)
from drape.runtime.deepsd import DeePSDModel, pose_outfit
from drape.runtime.sparse_rig import fit_poses as clip_poses
from drape.runtime.sparse_rig import sparse_rig


@pytest.fixture(scope="module")
def shipped():
    return DeePSDModel()


@pytest.fixture(scope="module")
def tshirt(shipped):
    body = load_body("neutral")
    o = generate_outfit("tshirt", vertices=1500, seed=11, body="neutral")
    return o, body, shipped.rig(o.vertices, o.faces, body)


def test_the_fit_poses_are_training_motions_never_validation_or_evaluation_ones():
    poses = fit_poses()
    assert poses.shape == (150, 24, 3) and np.isfinite(poses).all()
    cfg = DeePSDModel().manifest["training"]["config"]  # the shipped model's
    trained = {cfg["seed"] + 500 + i for i in range(cfg["procedural_motions"])}
    assert set(PROCEDURAL_SEEDS) <= trained
    v = cfg["validation"]
    assert not set(PROCEDURAL_SEEDS) & {*v["procedural_seeds"], *v["procedural_spread"]["seeds"]}


def test_pushed_targets_lie_outside_the_body_by_an_exact_distance(shipped, tshirt):
    o, body, rig = tshirt
    poses = load_clip("dance_b").poses[::10][:8].astype(np.float64)
    keys = shipped.pose_keys(poses)
    posed = pose_outfit(o.vertices, rig, keys, body.joints, poses)
    pushed = pushed_targets(o.vertices, rig, body.joints, poses, keys, body.vertices, body.faces, body.weights)
    moved = np.linalg.norm(pushed - posed, axis=2) > 0
    assert moved.any()
    pushed_sd = []
    for t, b in enumerate(body.pose(poses)):
        b = b.astype(np.float64)
        sd = MeshDistance(b, body.faces, vertex_normals(b, body.faces)).signed_distance(pushed[t].astype(np.float64))
        before = MeshDistance(b, body.faces).signed_distance(posed[t].astype(np.float64))
        # what was pushed lies at eps outside, nearly all of it: a point put at eps along its closest point's
        # interpolated normal can come nearer another face in a crease (0.11.0's rig: 2 of 397 pushed points,
        # under the chin and at the armpit, end 0.5 and 4 mm inside), never deeper than eps
        pushed_sd.append(sd[moved[t]])
        assert np.mean(sd[moved[t]] > EPS - 5e-4) >= 0.95
        # inside but not pushed: body parts farther than REACH from the garment at rest (a hand through the cloth)
        missed = (before < 0) & ~moved[t]
        assert missed.mean() <= 0.005, (missed.sum(), before[missed])
    pushed_sd = np.concatenate(pushed_sd)
    assert np.mean(pushed_sd > 0) >= 0.99 and pushed_sd.min() > -EPS, (np.mean(pushed_sd > 0), pushed_sd.min())


def test_cloth_deeper_than_deepest_is_left_where_it_is(shipped, tshirt):
    o, body, rig = tshirt
    poses = load_clip("dance_b").poses[::10][:8].astype(np.float64)
    keys = shipped.pose_keys(poses)
    posed = pose_outfit(o.vertices, rig, keys, body.joints, poses)
    for deepest, tight in ((0.0, None), (0.03, None), (None, (0.0, 1e-9))):
        pushed = pushed_targets(o.vertices, rig, body.joints, poses, keys, body.vertices, body.faces, body.weights,
                                deepest=deepest, tight=tight)
        moved = np.linalg.norm(pushed - posed, axis=2) > 0
        if tight is not None:  # no vertex lies on the body's vertices at rest: nothing is pushed
            assert not moved.any()
            continue
        for t, b in enumerate(body.pose(poses)):
            before = MeshDistance(b.astype(np.float64), body.faces).signed_distance(posed[t].astype(np.float64))
            assert np.all(before[moved[t]] > -deepest - 1e-3), (deepest, before[moved[t]].min())


def test_settle_rounds_put_out_again_what_lands_near_another_part(shipped, tshirt):
    """settle (with the surface's second reading): a pushed point that lands within 0.9 eps of another part of the
    body goes out again, so more of what is pushed lies at eps by an exact distance, and none less, on every frame;
    the same points are pushed."""
    o, body, rig = tshirt
    poses = load_clip("dance_b").poses[::10][:8].astype(np.float64)
    keys = shipped.pose_keys(poses)
    posed = pose_outfit(o.vertices, rig, keys, body.joints, poses)
    plain, settled = (pushed_targets(o.vertices, rig, body.joints, poses, keys, body.vertices, body.faces,
                                     body.weights, far_k=5, settle=n) for n in (0, 3))
    assert np.array_equal(np.any(plain != posed, axis=2), np.any(settled != posed, axis=2))
    moved = np.any(plain != posed, axis=2)
    at_eps = np.zeros((2, len(poses)))
    for t, b in enumerate(body.pose(poses)):
        b = b.astype(np.float64)
        exact = MeshDistance(b, body.faces, vertex_normals(b, body.faces))
        for i, p in enumerate((plain, settled)):
            at_eps[i, t] = np.sum(exact.signed_distance(p[t][moved[t]].astype(np.float64)) > EPS - 5e-4)
    assert np.all(at_eps[1] >= at_eps[0]) and at_eps[1].sum() > at_eps[0].sum(), at_eps


def test_the_answer_does_not_depend_on_the_threads(shipped, tshirt):
    o, body, rig = tshirt
    poses = fit_poses()[::5]
    keys = shipped.pose_keys(poses)
    one, two = (pushed_targets(o.vertices, rig, body.joints, poses, keys, body.vertices, body.faces, body.weights,
                               deepest=0.03, threads=n) for n in (1, 2))
    assert np.array_equal(one, two)


def test_a_garment_away_from_the_body_keeps_its_rig(shipped, tshirt):
    o, body, rig = tshirt
    far = o.vertices + np.array([0.0, 0.0, 2.0], dtype=np.float32)  # 2 m in front of the body
    poses = fit_poses()
    keys = shipped.pose_keys(poses)
    out = collision_fit(far, rig, body.joints, 4, poses, keys, body.vertices, body.faces, body.weights)
    assert np.array_equal(out.weights > 0, rig.weights > 0)
    assert np.abs(out.blend_shapes - rig.blend_shapes).max() <= 1e-6


def inside_share(verts, rig, model, body, clip):
    m = load_clip(clip)
    poses, trans = m.poses.astype(np.float64), m.trans.astype(np.float64)
    posed = pose_outfit(verts, rig, model.pose_keys(poses), body.joints, poses, trans)
    out = []
    for g, b in zip(posed[::6], body.pose(poses, trans)[::6], strict=True):
        b = b.astype(np.float64)
        out.append(np.mean(MeshDistance(b, body.faces).signed_distance(g.astype(np.float64)) < 0))
    return float(np.mean(out))


def test_the_fit_leaves_fewer_vertices_inside_on_clips_it_never_saw(shipped):
    body = load_body("male")
    o = generate_outfit("longsleeve", vertices=1500, seed=12, body="male")
    dense = shipped.rig(o.vertices, o.faces, body)
    fit = clip_poses(), shipped.pose_keys(clip_poses())
    collision = fit_poses(), shipped.pose_keys(fit_poses())
    plain = served_rig(o.vertices, dense, body, 4, fit, None)
    served = served_rig(o.vertices, dense, body, 4, fit, collision)
    assert np.array_equal(served.weights > 0, plain.weights > 0)  # the same joints, renormalised again
    assert np.abs(served.weights - plain.weights).max() <= 1e-6
    for clip in ("walk", "dance_b"):  # DeePSD's held-out clips, in no fit
        before, after = (inside_share(o.vertices, r, shipped, body, clip) for r in (plain, served))
        assert after < 0.8 * before, (clip, before, after)


def test_without_collision_poses_the_served_rig_is_the_sparse_rig(shipped, tshirt):
    o, body, rig = tshirt
    poses = clip_poses(40)
    fit = poses, shipped.pose_keys(poses)
    a = served_rig(o.vertices, rig, body, 4, fit, None)
    b = sparse_rig(o.vertices, rig, body.joints, 4, *fit)
    assert np.array_equal(a.weights, b.weights) and np.array_equal(a.blend_shapes, b.blend_shapes)


def test_the_engine_serves_the_collision_fit_rig_and_tells_the_two_apart(tshirt):
    from drape.runtime.engine import Engine

    o, body, _ = tshirt
    on, off = Engine(refine_workers=1), Engine(refine_workers=1, collision_fit=False)
    try:
        a, b = on.rig(o.vertices, o.faces, "neutral"), off.rig(o.vertices, o.faces, "neutral")
        assert a.outfit_id != b.outfit_id
        dense = on.model.rig(o.vertices, o.faces, body)
        ref = served_rig(o.vertices, dense, body, 4, on.fit_frames(), on.collision_frames(), o.faces)
        assert np.array_equal(a.rig.blend_shapes, ref.blend_shapes) and np.array_equal(a.rig.weights, ref.weights)
        assert np.array_equal(b.rig.blend_shapes, served_rig(o.vertices, dense, body, 4, off.fit_frames(), None).blend_shapes)
        assert not np.array_equal(a.rig.blend_shapes, b.rig.blend_shapes)
    finally:
        on.close()
        off.close()


def test_the_fits_edge_relaxation_lowers_the_edge_error_on_clips_it_never_saw(shipped):
    """With the outfit's faces the fit relaxes its targets toward the rest edge lengths (RELAX rounds, cloth on the
    body and the pushed vertices held, then pushed out again): on DeePSD's held-out clips the served jacket's edges
    stay nearer their rest lengths than the same fit's without the relaxation, with the same joints."""
    from drape.geometry.metrics import edge_length_error_mm

    body = load_body("female")
    o = generate_outfit("jacket", vertices=1500, seed=5, body="female")
    dense = shipped.rig(o.vertices, o.faces, body)
    fit = clip_poses(), shipped.pose_keys(clip_poses())
    collision = fit_poses(), shipped.pose_keys(fit_poses())
    plain = served_rig(o.vertices, dense, body, 4, fit, collision)  # no faces: no relaxation
    relaxed = served_rig(o.vertices, dense, body, 4, fit, collision, o.faces)
    assert np.array_equal(relaxed.weights, plain.weights)
    for clip in ("walk", "dance_b"):
        m = load_clip(clip)
        poses, trans = m.poses.astype(np.float64), m.trans.astype(np.float64)
        keys = shipped.pose_keys(poses)
        a, b = (edge_length_error_mm(pose_outfit(o.vertices, r, keys, body.joints, poses, trans), o.vertices, o.faces)
                for r in (plain, relaxed))
        assert b < 0.95 * a, (clip, a, b)
        # it trades a little cloth inside for it (walk: 0.46% -> 0.81%), less than it gains by the validation's
        # score (inside % + edge error mm, drape.training.deepsd_validation)
        inside = [100 * inside_share(o.vertices, r, shipped, body, clip) for r in (plain, relaxed)]
        assert inside[1] + b < inside[0] + a, (clip, inside, a, b)
