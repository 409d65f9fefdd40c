"""Retarget the DeepMimic humanoid clips (shipped in the `pybullet` wheel) to drape's body.

DeepMimic frames are [duration, root position (3), root quaternion (4),
chest (4), neck (4), right hip (4), right knee (1), right ankle (4),
right shoulder (4), right elbow (1), left hip (4), left knee (1),
left ankle (4), left shoulder (4), left elbow (1)]; quaternions are (w, x, y, z),
1-dof knees and elbows turn about the local z axis. The DeepMimic frame is
Y-up facing +X with its right side at +Z, its rest pose has the arms down.

Retargeting: global joint rotations are carried over to drape's frame (Y-up,
facing +Z); the arms are bridged from the arms-down rest to drape's T-pose
rest; the chest rotation is spread evenly over spine1..spine3; root motion is
scaled by the leg-length ratio and lifted so the feet meet the floor; clips are
resampled to 30 fps, and cyclic clips are tiled to at least 4 s.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from drape.assets.body import Body
from drape.assets.motion import Motion, resample, tile_cycle
from drape.geometry.rotations import (
    axis_angle_to_matrix,
    matrix_to_axis_angle,
    quaternion_to_matrix,
)
from drape.geometry.skeleton import JOINT_INDEX

# DeepMimic (x forward, y up, z right) -> drape (z forward, y up, x left)
DM_TO_DRAPE = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
DM_LEG_LENGTH = 0.421546 + 0.40987  # hip -> knee -> ankle offsets of humanoid3d
ATTRIBUTION = (
    "Motion clips retargeted from the DeepMimic humanoid3d reference motions "
    "(Peng et al., SIGGRAPH 2018) as shipped in the pybullet wheel (pybullet_data/data/motions)."
)


def _rot_z(angle: np.ndarray) -> np.ndarray:
    return axis_angle_to_matrix(np.stack([0 * angle, 0 * angle, angle], axis=-1))


def parse_frames(frames: np.ndarray) -> dict[str, np.ndarray]:
    """(T, 44) DeepMimic frames -> local rotation matrices (T, 3, 3) per joint and root position."""
    f = np.asarray(frames, dtype=np.float64)
    cols = iter(range(1, 44))

    def take(n: int) -> np.ndarray:
        idx = [next(cols) for _ in range(n)]
        return f[:, idx]

    out: dict[str, np.ndarray] = {"root_pos": take(3)}
    for name, width in (
        ("root", 4), ("chest", 4), ("neck", 4), ("r_hip", 4), ("r_knee", 1), ("r_ankle", 4),
        ("r_shoulder", 4), ("r_elbow", 1), ("l_hip", 4), ("l_knee", 1), ("l_ankle", 4),
        ("l_shoulder", 4), ("l_elbow", 1),
    ):
        v = take(width)
        out[name] = quaternion_to_matrix(v) if width == 4 else _rot_z(v[:, 0])
    return out


def _power(rot: np.ndarray, fraction: float) -> np.ndarray:
    return axis_angle_to_matrix(matrix_to_axis_angle(rot) * fraction)


def retarget(frames: np.ndarray, body: Body) -> tuple[np.ndarray, np.ndarray]:
    """(T, 44) DeepMimic frames -> (poses (T, 24, 3) rad, trans (T, 3) m) for `body`, feet not yet floored."""
    d = parse_frames(frames)
    C = DM_TO_DRAPE

    def conv(rot: np.ndarray) -> np.ndarray:  # a rotation expressed in drape's frame
        return C @ rot @ C.T

    T = len(frames)
    local = np.repeat(np.eye(3)[None, None], 24, axis=1).repeat(T, axis=0)
    J = JOINT_INDEX
    local[:, J["pelvis"]] = conv(d["root"])
    third = _power(conv(d["chest"]), 1.0 / 3.0)
    for name in ("spine1", "spine2", "spine3"):
        local[:, J[name]] = third
    local[:, J["neck"]] = conv(d["neck"])
    # arms: drape's rest has them along +-X, DeepMimic's hangs them down (-Y)
    bridge = {"left": _rot_z(np.array(-np.pi / 2))[()], "right": _rot_z(np.array(np.pi / 2))[()]}
    for side, s in (("left", "l"), ("right", "r")):
        b = bridge[side]
        local[:, J[f"{side}_shoulder"]] = conv(d[f"{s}_shoulder"]) @ b
        local[:, J[f"{side}_elbow"]] = b.T @ conv(d[f"{s}_elbow"]) @ b
        local[:, J[f"{side}_hip"]] = conv(d[f"{s}_hip"])
        local[:, J[f"{side}_knee"]] = conv(d[f"{s}_knee"])
        local[:, J[f"{side}_ankle"]] = conv(d[f"{s}_ankle"])
    poses = matrix_to_axis_angle(local)
    leg = float(body.joints[J["left_hip"], 1] - body.joints[J["left_ankle"], 1])
    scale = leg / DM_LEG_LENGTH
    root = d["root_pos"] @ C.T * scale
    trans = root - np.array([0.0, body.joints[0, 1], 0.0])
    trans[:, [0, 2]] -= trans[0, [0, 2]]
    return poses, trans


def foot_heights(motion: Motion, body: Body) -> np.ndarray:
    """Lowest foot point above the floor per frame, over both feet: (T,) metres.

    A foot vertex is one whose strongest skin weight is an ankle or foot joint.
    """
    feet = [JOINT_INDEX[n] for n in ("left_ankle", "right_ankle", "left_foot", "right_foot")]
    mask = np.isin(body.weights.argmax(axis=1), feet)
    verts = body.pose(motion.poses, motion.trans)[:, mask]
    return verts[..., 1].min(axis=1)


def floor_motion(motion: Motion, body: Body) -> Motion:
    """Shift the clip vertically so the body's lowest point meets the floor.

    The offset puts the 10th percentile of the per-frame lowest body point at y = 0:
    robust to a few frames of flight (jumps) or of stray contact.
    """
    lowest = body.pose(motion.poses, motion.trans)[..., 1].min(axis=1)
    trans = motion.trans.copy()
    trans[:, 1] -= np.percentile(lowest, 10)
    return Motion(motion.poses, trans, motion.fps, motion.name)


def import_clip(path: str | Path, body: Body, fps: float = 30.0, min_seconds: float = 4.0) -> Motion:
    """Read one DeepMimic clip file (JSON) and retarget it onto `body` at `fps`."""
    data = json.loads(Path(path).read_text())
    frames = np.asarray(data["Frames"], dtype=np.float64)
    if frames.ndim != 2 or frames.shape[1] != 44:
        raise ValueError(f"{path}: expected (T, 44) humanoid3d frames, got {frames.shape}")
    poses, trans = retarget(frames, body)
    src_fps = 1.0 / float(np.median(frames[:-1, 0])) if len(frames) > 1 else fps
    name = Path(path).stem.removeprefix("humanoid3d_")
    motion = resample(Motion(poses, trans, src_fps, name), fps)
    if data.get("Loop") == "wrap":
        motion = tile_cycle(motion, int(min_seconds * fps))
    return floor_motion(motion, body)


def deepmimic_clip_paths() -> list[Path]:
    """The humanoid3d clip files inside the installed pybullet_data package."""
    import pybullet_data  # asset dependency

    root = Path(pybullet_data.getDataPath()) / "data" / "motions"
    return sorted(root.glob("humanoid3d_*.txt"))
