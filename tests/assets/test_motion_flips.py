"""Rotation flips in motion capture (drape.assets.motion_flips): found where a joint jumps and comes back, slerped
over, and left alone in clean or merely fast motion; on the real CMU file where the flip was found (05_10_dance).

The 38 real clips before and after the repair: `.venv/bin/python -m bench.motion_flips` (docs/motion_import.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import Motion, import_motion
from drape.assets.motion_flips import _angles, find_flips, repair_flips
from drape.geometry.rotations import axis_angle_to_quaternion
from drape.geometry.skeleton import JOINT_INDEX, NUM_JOINTS
from tests.cmu_bvh import cmu_bvh

MOCAP = Path(__file__).resolve().parents[3] / "shared" / "data" / "mocap"
RIGHT_HIP, RIGHT_ANKLE = JOINT_INDEX["right_hip"], JOINT_INDEX["right_ankle"]


def smooth_motion(frames: int = 240, fps: float = 120.0, seed: int = 0) -> Motion:
    """Every joint turning smoothly (at most ~6 rad/s), root walking forward."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None, None] / fps
    amp, freq, phase = rng.uniform(0.1, 0.6, (3, 1, NUM_JOINTS, 3))
    poses = amp * np.sin(2 * np.pi * (0.5 + 1.5 * freq) * t + 6 * phase)
    trans = np.stack([np.zeros(frames), np.full(frames, 0.9), np.arange(frames) / fps], axis=1)
    return Motion(poses.astype(np.float32), trans.astype(np.float32), fps, "smooth")


def half_turn_about(poses: np.ndarray, joint: int, frames: slice, axis: np.ndarray) -> np.ndarray:
    """poses with `joint` turned a further half turn about `axis` (its parent's frame) on `frames`."""
    from scipy.spatial.transform import Rotation

    out = poses.copy()
    r = Rotation.from_rotvec(out[frames, joint].astype(np.float64))
    out[frames, joint] = (Rotation.from_rotvec(np.pi * axis / np.linalg.norm(axis)) * r).as_rotvec()
    return out


def test_a_flip_that_turns_back_is_found_and_slerped_over():
    """A knee-swing flip as in 05_10_dance: the hip turned half a turn for frames 100-108 and the ankle turned with
    it. Both are found as one span, and the repair lands within 0.1 rad of the motion before the flip was put in."""
    clean = smooth_motion()
    poses = half_turn_about(clean.poses, RIGHT_HIP, slice(100, 109), np.array([0.1, -1.0, 0.2]))
    poses = half_turn_about(poses, RIGHT_ANKLE, slice(100, 109), np.array([0.0, 1.0, 0.3]))
    flipped = Motion(poses, clean.trans, clean.fps, "flipped")

    flips = find_flips(flipped.poses, flipped.fps)
    assert [(f.first, f.last, f.joints) for f in flips] == [(100, 108, (RIGHT_HIP, RIGHT_ANKLE))]
    assert flips[0].jump_rad > 3.0
    assert "frames 100-108 (right_hip, right_ankle" in flips[0].describe()

    repaired, found = repair_flips(flipped)
    assert found == flips
    q0 = axis_angle_to_quaternion(clean.poses.astype(np.float64))
    q1 = axis_angle_to_quaternion(repaired.poses.astype(np.float64))
    err = _angles(q0, q1)
    assert err[100:109].max() < 0.1  # slerp across 0.08 s of smooth motion
    assert err[:100].max() < 1e-5 and err[109:].max() < 1e-5  # the frames outside the span are untouched
    np.testing.assert_array_equal(repaired.trans, flipped.trans)


def test_clean_or_fast_motion_and_a_jump_that_stays_are_left_alone():
    clean = smooth_motion()
    assert find_flips(clean.poses, clean.fps) == []
    assert repair_flips(clean)[0] is clean
    # a real, fast swing there and back at 30 fps: 1.2 rad a frame is 36 rad/s, under FLIP_RAD_PER_S; the same
    # frames at 120 fps (144 rad/s) are a flip
    poses = smooth_motion(frames=60, fps=30.0).poses.copy()
    poses[:, RIGHT_HIP] = 0.0
    poses[21:23, RIGHT_HIP, 0] = 1.2
    assert find_flips(poses, 30.0) == []
    assert [(f.first, f.last) for f in find_flips(poses, 120.0)] == [(21, 22)]
    # a jump that does not come back within MAX_SPAN_S (a cut in the capture, not a flip)
    cut = half_turn_about(clean.poses, RIGHT_HIP, slice(100, None), np.array([0.0, 1.0, 0.0]))
    assert find_flips(cut, clean.fps) == []


def test_import_repairs_by_default_and_keeps_the_file_with_flips_false():
    """A clean BVH imports bit for bit the same either way; the summary names what was repaired."""
    data = cmu_bvh(121)
    body = load_body("neutral")
    a, b = import_motion(data, body), import_motion(data, body, flips=False)
    assert a.flips == () and "rotation flip" not in a.summary()
    np.testing.assert_array_equal(a.motion.poses, b.motion.poses)


@pytest.mark.skipif(not (MOCAP / "05_10_dance.bvh").exists(), reason=f"the real CMU clips are not at {MOCAP}")
def test_the_real_clip_with_a_knee_swing_flip():
    """05_10_dance.bvh: the right thigh turns 3.14 rad between source frames 243 and 244 and back between 252 and
    253 (the knee moves ~30 cm in 1/120 s, the foot stays). Imported, the flip is one span and no joint turns more
    than 0.6 rad in a frame (the clip's own motion: 0.51 rad); with flips=False the jump is there."""
    body = load_body("neutral")
    data = (MOCAP / "05_10_dance.bvh").read_bytes()
    r = import_motion(data, body, floor=False)
    assert [(f.first, f.last) for f in r.flips] == [(244, 252)]
    assert RIGHT_HIP in r.flips[0].joints
    assert "repaired 1 rotation flip(s)" in r.summary()
    turns = [_angles(q[:-1], q[1:]).max() for q in (axis_angle_to_quaternion(m.poses.astype(np.float64)) for m in
                                                   (r.motion, import_motion(data, body, floor=False,
                                                                            flips=False).motion))]
    assert turns[0] < 0.6 < 3.0 < turns[1]


@pytest.mark.skipif(not (MOCAP / "05_10_dance.bvh").exists(), reason=f"the real CMU clips are not at {MOCAP}")
def test_training_loaders_keep_flips_unless_the_config_asks(tmp_path, monkeypatch):
    """deepsd_data.mocap_motion (the DeePSD and MGN trainings' real clips) keeps the flips by default, so the
    shipped configs re-create their data; flips=True (an MGN outer config's `"mocap": {"flips": "repair"}`)
    repairs them, cached apart; any other value of that key is refused."""
    from drape.training import deepsd_data
    from drape.training.layers_outer import OuterTask

    monkeypatch.setattr(deepsd_data, "CACHE", tmp_path / "outfits")
    kept, _ = deepsd_data.mocap_motion(MOCAP, "05_10_dance", 30.0)
    repaired, _ = deepsd_data.mocap_motion(MOCAP, "05_10_dance", 30.0, flips=True)
    assert sorted(p.name for p in (tmp_path / "mocap").iterdir()) == [
        "05_10_dance_neutral_30.npz", "05_10_dance_neutral_30_repaired.npz"]
    turn = [_angles(q[:-1], q[1:]).max() for q in (axis_angle_to_quaternion(p.astype(np.float64))
                                                   for p in (kept, repaired))]
    assert turn[1] < 1.0 < turn[0]  # at 30 fps the flip is a turn of over 1 rad a frame; repaired it is gone

    task = OuterTask.__new__(OuterTask)  # only clip_sequences' config check runs before any clip is read
    task.cfg = {"mocap": {"flips": "fix"}}
    with pytest.raises(ValueError, match="mocap.flips must be 'keep' or 'repair'"):
        task.clip_sequences(["05_10_dance"], 0.008)
