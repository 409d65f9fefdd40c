"""The blocked posing of `pose_outfit` (ORT sgemm + numpy passes) against the plain formulation:
`linear_blend_skinning` of rest + keys @ D with `forward_kinematics`, to 1e-5 m."""

import numpy as np
import pytest

from drape.geometry.lbs import linear_blend_skinning
from drape.geometry.skeleton import PARENTS, forward_kinematics
from drape.runtime import deepsd
from drape.runtime.deepsd import MODEL_DIR, Rig, gemm_model, pose_outfit

TOL = 1e-5  # metres


def random_rig(n: int = 300, p: int = 128, seed: int = 0):
    """rest (N, 3) m, a rig with weights (N, 24) summing to 1 (a few joints dominating) and blend
    shapes (P, N, 3) m sized so that keys ~ N(0, 1) give offsets of 1-5 cm, rest joints
    (24, 3) m."""
    rng = np.random.default_rng(seed)
    rest = (rng.standard_normal((n, 3)) * [0.2, 0.5, 0.15] + [0, 1.0, 0]).astype(np.float32)
    w = rng.random((n, 24)) ** 6
    weights = (w / w.sum(1, keepdims=True)).astype(np.float32)
    shapes = (rng.standard_normal((p, n, 3)) * 0.03 / np.sqrt(p)).astype(np.float32)
    joints = rng.standard_normal((24, 3)) * 0.3 + [0, 1.0, 0]
    return rest, Rig(weights, shapes), joints


def random_motion(t: int, p: int = 128, seed: int = 1):
    """keys (T, P) float32, poses (T, 24, 3) radians (up to ~1.5 rad a joint), translation
    (T, 3) m."""
    rng = np.random.default_rng(seed)
    keys = rng.standard_normal((t, p)).astype(np.float32)
    poses = rng.standard_normal((t, 24, 3)) * 0.6
    trans = rng.standard_normal((t, 3)) * 0.5 + [0.3, 0.9, -1.2]
    return keys, poses, trans


def reference(rest, rig, keys, joints, poses, trans):
    """The plain formulation: offsets as one product, FK, then the einsum LBS."""
    p, n, _ = rig.blend_shapes.shape
    offsets = (keys.astype(np.float64) @ rig.blend_shapes.reshape(p, 3 * n)).reshape(-1, n, 3)
    transforms, _ = forward_kinematics(poses, joints, PARENTS, trans)
    return linear_blend_skinning(rest[None] + offsets, rig.weights, transforms)


@pytest.fixture(scope="module")
def case():
    rest, rig, joints = random_rig()
    keys, poses, trans = random_motion(37)  # 37: prime, a multiple of no block size below
    return rest, rig, joints, keys, poses, trans, reference(rest, rig, keys, joints, poses, trans)


def test_offsets_are_realistic(case):
    rest, rig, joints, keys, poses, trans, ref = case
    offsets = keys @ rig.blend_shapes.reshape(len(keys[0]), -1)
    size = np.linalg.norm(offsets.reshape(-1, 3), axis=1)
    assert 0.01 < np.median(size) < 0.06 and size.max() < 0.2
    assert np.ptp(ref, axis=(0, 1)).min() > 1.0  # the poses move the outfit by metres


@pytest.mark.parametrize("block_frames", [None, 1, 4, 5, 36])
def test_whole_call_equals_reference(case, monkeypatch, block_frames):
    """Blocks of 1, 4, 5 and 36 frames (37 frames leave a short last block), and the default
    (all 37 frames in one block at 300 vertices)."""
    rest, rig, joints, keys, poses, trans, ref = case
    if block_frames is not None:
        monkeypatch.setattr(deepsd, "BLOCK_BYTES", 48 * len(rest) * block_frames)
    got = pose_outfit(rest, rig, keys, joints, poses, trans)
    assert got.shape == ref.shape and got.dtype == np.float32
    assert np.abs(got - ref).max() <= TOL


@pytest.mark.parametrize("chunk", [1, 7, 32])
def test_chunked_calls_equal_reference(case, chunk):
    rest, rig, joints, keys, poses, trans, ref = case
    parts = [pose_outfit(rest, rig, keys[s : s + chunk], joints, poses[s : s + chunk],
                         trans[s : s + chunk]) for s in range(0, len(keys), chunk)]
    assert np.abs(np.concatenate(parts) - ref).max() <= TOL


def test_numpy_gemm_fallback_equals_reference(case, monkeypatch):
    """Without onnxruntime the GEMMs are numpy's; same result."""
    rest, rig, joints, keys, poses, trans, ref = case
    monkeypatch.setattr(deepsd, "BLOCK_BYTES", 48 * len(rest) * 6)
    got = deepsd._pose(rest, rig, keys, joints, poses, trans, None, deepsd._numpy_gemm)
    assert np.abs(got - ref).max() <= TOL


def test_out_array_flat_poses_and_no_translation():
    rest, rig, joints = random_rig(n=101, p=16, seed=3)
    keys, poses, _ = random_motion(5, p=16, seed=4)
    ref = reference(rest, rig, keys, joints, poses, None)
    out = np.full((5, 101, 3), np.nan, dtype=np.float32)
    got = pose_outfit(rest.astype(np.float64), rig, keys, joints, poses.reshape(5, 72), None,
                      out=out)
    assert got is out and np.abs(out - ref).max() <= TOL
    with pytest.raises(ValueError, match="out must be"):
        pose_outfit(rest, rig, keys, joints, poses, None,
                    out=np.empty((5, 101, 3), dtype=np.float64))
    with pytest.raises(ValueError, match="poses for"):
        pose_outfit(rest, rig, keys, joints, poses[:4], None)
    assert pose_outfit(rest, rig, keys[:0], joints, poses[:0], None).shape == (0, 101, 3)


@pytest.mark.parametrize("trans_b", [False, True])
def test_hand_written_gemm_model_is_valid_onnx(trans_b):
    onnx = pytest.importorskip("onnx")
    model = onnx.load_from_string(gemm_model(trans_b))
    onnx.checker.check_model(model, full_check=True)
    node = model.graph.node[0]
    trans = [a.i for a in node.attribute if a.name == "transB"]
    assert node.op_type == "Gemm" and trans == ([1] if trans_b else [])


@pytest.mark.skipif(not (MODEL_DIR / "manifest.json").exists(), reason="no shipped model")
def test_engine_pose_chunks_with_shipped_model():
    """The shipped model through `Engine.pose_chunks` (32-frame chunks) against the reference on
    all frames at once."""
    from drape.assets.body import load_body
    from drape.assets.motion import load_clip
    from drape.assets.outfits import generate_outfit
    from drape.runtime.engine import Engine

    engine = Engine()
    try:
        o = generate_outfit("tshirt", vertices=800, seed=3)
        outfit = engine.rig(o.vertices, o.faces, "neutral")
        clip = load_clip("walk")
        idx = np.arange(70) % clip.num_frames
        poses, trans = clip.poses[idx], clip.trans[idx]
        got = np.concatenate(list(engine.pose_chunks(outfit, poses, trans, chunk=32)))
        keys = engine.model.pose_keys(poses)
        joints = load_body("neutral").joints
        ref = reference(outfit.vertices, outfit.rig, keys, joints, poses, trans)
        assert got.shape == (70, len(o.vertices), 3)
        assert np.abs(got - ref).max() <= TOL
    finally:
        engine.close()
