"""MGN's outer-layer network: its ONNX export against torch at two sequence lengths, the runtime's windowed,
blended posing against the training's torch formulation, the window helpers and the motion features (a freshly
initialised model on a small generated outer layer)."""

import numpy as np
import pytest
import torch

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import split_outfit
from drape.export.layers import export_outer
from drape.geometry.character_space import MOTION_FEATURES, motion_features
from drape.geometry.rotations import axis_angle_to_matrix
from drape.geometry.skeleton import PARENTS
from drape.models.layers import OuterConfig, OuterTransformer
from drape.runtime.deepsd import pose_outfit
from drape.runtime.layers import OuterModel, blend_windows, window_starts
from drape.training import physics
from drape.training.layers_inner import body_weights

KI = 12


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(0)
    _, (v, f) = split_outfit("tanktop,longsleeve", 1200, seed=3)
    model = OuterTransformer(OuterConfig(num_vertices=len(v), num_inner_keys=KI, num_basis=16, d_model=32,
                                         feedforward=64, window=8, basis_init=0.01))
    rng = np.random.default_rng(5)
    model.set_normalization(torch.as_tensor(rng.normal(0.3, 2.0, size=(50, MOTION_FEATURES)), dtype=torch.float32),
                            torch.as_tensor(rng.normal(0.1, 0.03, size=(50, KI)), dtype=torch.float32))
    model.eval()
    body = load_body("neutral")
    w = body_weights(v, body, 4)
    out = tmp_path_factory.mktemp("mgn_outer")
    export_outer(model, out, vertices=v, faces=f, weights=w, manifest={
        "served": "mgn_outer", "inner_network": {"pose_sha256": "x"}, "config": {"thickness": [0.004, 0.012]}})
    return model, v, f, w, body, out


def inputs(windows: int, frames: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(windows, frames, MOTION_FEATURES)).astype(np.float32),
            rng.uniform(0.004, 0.012, size=(windows, 1)).astype(np.float32),
            rng.normal(size=(windows, frames, KI)).astype(np.float32))


def test_outer_network_matches_torch_at_two_lengths(exported):
    model, *_, out = exported
    net = OuterModel(out)
    for windows, frames in ((3, 8), (40, 3)):
        m, h, k = inputs(windows, frames, frames)
        with torch.no_grad():
            ref = model.coefficients(torch.from_numpy(m), torch.from_numpy(h), torch.from_numpy(k)).numpy()
        got = net.session.run(["outer_keys"], {"motion": m, "thickness": h, "inner_keys": k})[0]
        assert got.shape == (windows, frames, 16) and np.abs(got - ref).max() <= 1e-4
    # the thickness is an input that matters
    m, h, k = inputs(1, 8, 0)
    a = net.session.run(None, {"motion": m, "thickness": h * 0 + 0.004, "inner_keys": k})[0]
    b = net.session.run(None, {"motion": m, "thickness": h * 0 + 0.012, "inner_keys": k})[0]
    assert np.abs(a - b).max() > 1e-4


@pytest.mark.parametrize("frames", [5, 8, 30, 61])
def test_served_posing_equals_the_trained_one(exported, frames):
    """The runtime (features, windows through ORT, blended keys, the batched posing of a rig) against torch on
    each window (offsets, FK, LBS), blended the same way: one network, two formulations."""
    model, v, _, w, body, out = exported
    net = OuterModel(out)
    clip = load_clip("dance_b")
    poses, trans = clip.poses[:frames].astype(np.float32), clip.trans[:frames].astype(np.float32)
    inner_keys = np.random.default_rng(frames).normal(size=(frames, KI)).astype(np.float32)
    served = pose_outfit(net.vertices, net.rig, net.pose_keys(poses, trans, 30.0, 0.007, inner_keys, body.joints),
                         body.joints, poses, trans)
    feats = motion_features(poses, trans, body.joints, PARENTS, 30.0)
    starts, length = window_starts(frames, 8)
    with torch.no_grad():
        offsets = np.stack([model(torch.from_numpy(feats[s:s + length][None]), torch.full((1, 1), 0.007),
                                  torch.from_numpy(inner_keys[s:s + length][None]))[0].numpy() for s in starts])
        blended = blend_windows(offsets.reshape(len(starts), length, -1), starts, frames).reshape(frames, -1, 3)
        pt = torch.from_numpy(poses)
        ref = physics.lbs(torch.from_numpy(v) + torch.from_numpy(blended), torch.from_numpy(w),
                          physics.skinning_transforms(pt, torch.from_numpy(body.joints).float())).numpy()
    ref = ref + trans[:, None]
    assert np.abs(blended).max() > 1e-3  # the basis moves the garment: the comparison is not trivial
    assert np.abs(served - ref).max() <= 1e-4


def test_windows_cover_every_frame_and_blend_to_the_mean():
    for frames, window in ((1, 30), (29, 30), (30, 30), (31, 30), (100, 30), (301, 30), (10, 1)):
        starts, length = window_starts(frames, window)
        assert length == min(frames, window) and starts[0] == 0 and starts[-1] + length == frames
        assert np.all(np.diff(starts) <= max(window // 2, 1))
        ones = blend_windows(np.ones((len(starts), length, 2)), starts, frames)
        assert np.allclose(ones, 1.0)
        ramp = np.stack([np.arange(s, s + length, dtype=np.float64)[:, None] for s in starts])
        assert np.allclose(blend_windows(ramp, starts, frames)[:, 0], np.arange(frames), atol=1e-4)


def test_motion_features_do_not_depend_on_where_the_body_stands_or_faces():
    body = load_body("neutral")
    clip = load_clip("walk")
    poses, trans = clip.poses[:20].copy(), clip.trans[:20].copy()
    f = motion_features(poses, trans, body.joints, PARENTS, 30.0)
    assert f.shape == (20, MOTION_FEATURES) and np.isfinite(f).all()
    # turn the whole motion 90 degrees about +Y and move it: the root's rotation and the path turn together
    turn = axis_angle_to_matrix(np.array([0.0, np.pi / 2, 0.0]))
    from drape.geometry.rotations import matrix_to_axis_angle

    moved = poses.copy()
    moved[:, 0] = matrix_to_axis_angle(turn @ axis_angle_to_matrix(poses[:, 0]))
    root = body.joints[0]
    moved_trans = (turn @ (trans + root).T).T - root + np.array([3.0, 0.0, -2.0])
    g = motion_features(moved, moved_trans, body.joints, PARENTS, 30.0)
    assert np.abs(f - g).max() < 1e-4
    # standing still: no velocity, no spin; gravity straight down the body's -Y at rest pose
    still = motion_features(np.zeros((4, 24, 3)), np.zeros((4, 3)), body.joints, PARENTS, 30.0)
    assert np.allclose(still[:, 69:72], [0, -1, 0]) and np.allclose(still[:, 72:], 0)
    # a root moving at 1.5 m/s along the body's +Z reads as 1.5 m/s forward
    walk = np.zeros((4, 3))
    walk[:, 2] = np.arange(4) * 0.05
    assert np.allclose(motion_features(np.zeros((4, 24, 3)), walk, body.joints, PARENTS, 30.0)[:, 72:75],
                       [0, 0, 1.5], atol=1e-5)
