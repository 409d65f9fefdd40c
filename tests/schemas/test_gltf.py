"""The GLB writer against an independent reading of the glTF spec (glb_player) and the Khronos
validator: a skinned, morphed, animated outfit plays back as drape poses it; weights pass the
validator's normalisation rules; vertex animations replay their stream."""

import numpy as np
import pytest
from glb_player import GlbPlayer
from gltf_validator import validate

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.geometry.lbs import linear_blend_skinning, rest_space_offsets
from drape.geometry.skeleton import forward_kinematics
from drape.schemas.gltf import (
    Animation,
    Skeleton,
    SkinnedMesh,
    skin_sets,
    skinned_glb,
    split_uv_seams,
    vertex_animation_glb,
)


def test_skin_sets_are_normalised_sorted_and_never_repeat_a_joint():
    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.full(24, 0.3), size=500)
    w[:5] = 0
    w[:5, 3] = 1  # single-influence vertices
    joints, ws = skin_sets(w)
    assert joints.shape == ws.shape and joints.shape[1] % 4 == 0 and ws.dtype == np.float32
    assert np.all(np.abs(ws.sum(axis=1, dtype=np.float32) - 1) <= 2e-7 * (ws > 0).sum(axis=1))
    assert np.all(np.diff(ws, axis=1)[:, :-1][ws[:, 1:-1] > 0] <= 1e-7)  # largest first
    for j, x in zip(joints, ws, strict=True):
        used = j[x > 0]
        assert len(set(used)) == len(used) and len(set(j)) >= len(j) - (x == 0).sum()
    dense = np.zeros_like(w)
    np.add.at(dense, (np.arange(len(w))[:, None].repeat(joints.shape[1], 1), joints), ws)
    assert np.abs(dense - w).max() < 2e-5  # only weights under MIN_WEIGHT were dropped


@pytest.fixture(scope="module")
def scene():
    body = load_body("neutral")
    rng = np.random.default_rng(1)
    idx = rng.choice(len(body.vertices), 400, replace=False)
    verts = body.vertices[idx] * 1.05
    faces = np.stack([np.arange(398), np.arange(1, 399), np.arange(2, 400)], 1)
    weights = body.weights[idx]
    targets = rng.normal(scale=0.01, size=(6, 400, 3)).astype(np.float32)
    clip = load_clip("dance_a")
    poses, trans = clip.poses[:40], clip.trans[:40]
    keys = rng.uniform(-0.5, 1.5, size=(40, 6)).astype(np.float32)
    return body, verts, faces, weights, targets, poses, trans, keys


def test_an_animated_skinned_morphed_mesh_plays_back_as_drape_poses_it(scene):
    body, verts, faces, weights, targets, poses, trans, keys = scene
    transforms, _ = forward_kinematics(poses, body.joints, body.parents, trans)
    # refinement-like corrections: a few vertices pushed 5 mm along +x in world space on some frames
    world = np.zeros((40, 400, 3), np.float32)
    world[::3, :20, 0] = 0.005
    corrections = [(np.flatnonzero(world[t].any(1)), rest_space_offsets(world[t][world[t].any(1)],
                                                                         weights[world[t].any(1)],
                                                                         transforms[t, :, :3, :3]))
                   for t in range(40)]
    glb = skinned_glb(Skeleton(body.joint_names, body.parents, body.joints),
                      [SkinnedMesh("outfit", verts, faces, weights, targets, tuple("abcdef")),
                       SkinnedMesh("body", body.vertices, body.faces, body.weights)],
                      Animation(poses, trans, 30.0, keys, corrections))
    report = validate(glb)
    assert report["errors"] == 0, report["messages"]
    rest = verts[None] + np.einsum("tp,pnc->tnc", keys, targets)
    want = linear_blend_skinning(rest, weights, transforms) + world
    player = GlbPlayer(glb)
    for t in (0, 3, 17, 39):
        assert np.abs(player.positions("outfit", t) - want[t]).max() < 1e-5, t
        assert np.abs(player.positions("body", t) - body.pose(poses[t:t + 1], trans[t:t + 1])[0]).max() < 1e-5
    assert np.abs(player.positions("outfit") - verts).max() < 1e-6  # rest: no animation applied
    assert player.doc.meshes[0].extras["targetNames"][:6] == list("abcdef")
    assert [n.name for n in player.doc.nodes[:24]] == list(body.joint_names)


def test_texture_coordinates_split_seams_and_play_back_as_the_mesh_without_them(scene):
    """A garment's UVs (per face corner, OBJ's convention) go out as TEXCOORD_0 (glTF's: v from the top). A vertex
    with two UVs (a seam) is written twice, at the same place, with the same weights, morph targets and
    corrections: posed by an independent player, every copy is where the vertex is without UVs."""
    body, verts, faces, weights, targets, poses, trans, keys = scene
    rng = np.random.default_rng(3)
    per_vertex = rng.uniform(0, 1, size=(len(verts), 2)).astype(np.float32)
    uv_corners = per_vertex[faces]
    uv_corners[::2, 0] += 1.0  # every other face another island: their shared vertices lie on seams
    transforms, _ = forward_kinematics(poses[:4], body.joints, body.parents, trans[:4])
    world = np.zeros((4, 400, 3), np.float32)
    world[1, 10:30, 0] = 0.004
    moved = world[1].any(1)
    corrections = [(np.zeros(0, np.int64), np.zeros((0, 3), np.float32))] * 4
    corrections[1] = (np.flatnonzero(moved), rest_space_offsets(world[1][moved], weights[moved],
                                                                 transforms[1, :, :3, :3]))
    skeleton = Skeleton(body.joint_names, body.parents, body.joints)
    glb = skinned_glb(skeleton, [SkinnedMesh("outfit", verts, faces, weights, targets, tuple("abcdef"),
                                             uv_corners)], Animation(poses[:4], trans[:4], 30.0, keys[:4], corrections))
    report = validate(glb)
    assert report["errors"] == 0, report["messages"]
    source, written_faces, uv = split_uv_seams(faces, uv_corners, len(verts))
    assert len(source) > len(verts) and set(source.tolist()) == set(range(len(verts)))
    assert np.array_equal(source[written_faces], faces)  # every face on copies of its own vertices
    player = GlbPlayer(glb)
    prim = player.doc.meshes[0].primitives[0]
    texcoord = player.accessor(prim.attributes.TEXCOORD_0)
    np.testing.assert_allclose(texcoord[written_faces][..., 0], uv_corners[..., 0])
    np.testing.assert_allclose(1.0 - texcoord[written_faces][..., 1], uv_corners[..., 1], atol=1e-7)
    rest = verts[None] + np.einsum("tp,pnc->tnc", keys[:4], targets)
    want = linear_blend_skinning(rest, weights, transforms) + world
    for t in range(4):
        assert np.abs(player.positions("outfit", t) - want[t][source]).max() < 1e-5, t
    # rest normals (a viewer shades a mesh without them flat): unit length, one per place, so a seam's copies
    # share theirs (their side: tests/service/test_texture_coordinates.py, on a garment)
    normal = player.accessor(prim.attributes.NORMAL)
    assert normal.shape == (len(source), 3) and np.allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-6)
    copies = source[:-1] == source[1:]  # adjacent copies of one vertex
    assert copies.any() and np.allclose(normal[:-1][copies], normal[1:][copies])


def test_a_vertex_animation_replays_its_stream_dense_and_sparse():
    rng = np.random.default_rng(2)
    frames = np.repeat(rng.normal(size=(1, 300, 3)).astype(np.float32), 12, axis=0)
    frames[1::2] += rng.normal(scale=0.01, size=(6, 300, 3)).astype(np.float32)  # dense frames
    frames[2::4, :7] += 0.02  # sparse frames
    faces = np.stack([np.arange(298), np.arange(1, 299), np.arange(2, 300)], 1)
    glb = vertex_animation_glb(frames, faces, fps=24.0)
    report = validate(glb)
    assert report["errors"] == 0, report["messages"]
    player = GlbPlayer(glb)
    for t in range(12):
        assert np.abs(player.positions("garment", t) - frames[t]).max() < 1e-6, t
    assert any(a.sparse is not None for a in player.doc.accessors)


def _declared_bounds_hold(glb: bytes) -> None:
    """Every accessor's declared min/max is its elements' min/max after sparse substitution (glTF 2.0 §3.6.2.5;
    the validator's ACCESSOR_MIN_MISMATCH / ACCESSOR_MAX_MISMATCH errors)."""
    player = GlbPlayer(glb)
    for i, acc in enumerate(player.doc.accessors):
        if not acc.min and not acc.max:  # none declared (pygltflib reads that as [])
            continue
        data = player.accessor(i)
        assert acc.min == data.min(axis=0).tolist() and acc.max == data.max(axis=0).tolist(), i


def test_a_correction_of_every_vertex_declares_its_own_bounds():
    # a refinement that moves every vertex of a frame: its sparse target holds no zero, so 0 is no bound of it
    body = load_body("neutral")
    n = 30
    verts = body.vertices[:n]
    faces = np.stack([np.arange(n - 2), np.arange(1, n - 1), np.arange(2, n)], 1)
    offsets = np.random.default_rng(3).uniform(0.001, 0.004, size=(n, 3)).astype(np.float32)
    corrections = [(np.arange(n), offsets), (np.arange(5), -offsets[:5])]
    glb = skinned_glb(Skeleton(body.joint_names, body.parents, body.joints),
                      [SkinnedMesh("outfit", verts, faces, body.weights[:n])],
                      Animation(np.zeros((2, 24, 3)), np.zeros((2, 3)), 30.0, None, corrections))
    _declared_bounds_hold(glb)


@pytest.mark.parametrize("joints", [1, 3, 6])
def test_skin_sets_of_a_skeleton_whose_joint_count_is_no_multiple_of_4(joints):
    # every vertex uses every joint: the sets must still come in whole 4s, hold all of it, and name real joints
    w = np.full((5, joints), 1.0 / joints)
    j, ws = skin_sets(w)
    assert j.shape == ws.shape and j.shape[1] % 4 == 0 and j.shape[1] >= joints
    assert j.max() < joints
    assert np.all(np.abs(ws.sum(axis=1, dtype=np.float32) - 1) <= 2e-7 * joints)
    for row, x in zip(j, ws, strict=True):
        assert sorted(row[x > 0].tolist()) == list(range(joints))
    skeleton = Skeleton(tuple(f"j{k}" for k in range(joints)), np.arange(joints) - 1,
                        np.arange(joints * 3, dtype=float).reshape(joints, 3) * 0.1)
    glb = skinned_glb(skeleton, [SkinnedMesh("m", np.eye(3, dtype=np.float32)[[0, 1, 2, 0, 1]] + [[0, 0, k]
                                                                                            for k in range(5)],
                                             np.array([[0, 1, 2], [2, 3, 4]]), w)])
    attrs = GlbPlayer(glb).doc.meshes[0].primitives[0].attributes
    assert attrs.JOINTS_0 is not None and attrs.WEIGHTS_0 is not None


def test_a_glb_is_written_without_copies_of_its_buffer_beyond_the_file():
    # the binary buffer (here ~ the stream's bytes) is built once and copied once into the file: not again for the
    # GLB container (pygltflib's save_to_bytes copies every bufferView into a new buffer, then joins it once more)
    import tracemalloc

    rng = np.random.default_rng(4)
    frames = rng.normal(size=(40, 10_000, 3)).astype(np.float32)
    faces = np.stack([np.arange(9_998), np.arange(1, 9_999), np.arange(2, 10_000)], 1)
    tracemalloc.start()
    try:
        glb = vertex_animation_glb(frames, faces, fps=30.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2.5 * len(glb), (peak, len(glb))
    player = GlbPlayer(glb)
    for t in (0, 1, 39):
        assert np.abs(player.positions("garment", t) - frames[t]).max() < 1e-6, t
