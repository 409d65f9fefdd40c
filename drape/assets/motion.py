"""Motions: a pose sequence on the 24-joint skeleton, its loaders and time operations.

poses: (T, 24, 3) float32 axis-angle radians (local, relative to the T-pose rest);
trans: (T, 3) float32 metres (root translation added to every joint); fps: frames/s.
Embedded clips live at drape/assets/motions/<name>.npz with exactly those three keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from drape.geometry.rotations import (
    axis_angle_to_quaternion,
    quaternion_multiply,
    quaternion_to_axis_angle,
)
from drape.geometry.skeleton import NUM_JOINTS, as_pose_array

MOTIONS_DIR = Path(__file__).parent / "motions"


@dataclass(frozen=True)
class Motion:
    """poses (T, 24, 3) float32 rad, trans (T, 3) float32 m, fps frames/s, name."""

    poses: np.ndarray
    trans: np.ndarray
    fps: float = 30.0
    name: str = ""

    def __post_init__(self) -> None:
        poses = as_pose_array(self.poses).astype(np.float32)
        trans = np.asarray(self.trans, dtype=np.float32).reshape(-1, 3)
        if len(trans) != len(poses):
            raise ValueError(f"trans has {len(trans)} frames, poses {len(poses)}")
        if not (np.isfinite(poses).all() and np.isfinite(trans).all()):
            raise ValueError("motion contains NaN or inf")
        if not self.fps > 0:
            raise ValueError(f"fps must be positive, got {self.fps}")
        object.__setattr__(self, "poses", poses)
        object.__setattr__(self, "trans", trans)
        object.__setattr__(self, "fps", float(self.fps))

    @property
    def num_frames(self) -> int:
        return len(self.poses)

    def save(self, path: str | Path) -> None:
        np.savez_compressed(path, poses=self.poses, trans=self.trans, fps=np.float32(self.fps))


def list_clips() -> list[str]:
    """Names of the embedded clips, sorted."""
    return sorted(p.stem for p in MOTIONS_DIR.glob("*.npz"))


@lru_cache(maxsize=64)
def load_clip(name: str) -> Motion:
    """Load an embedded clip by name (KeyError if there is none)."""
    if name not in list_clips():
        raise KeyError(f"unknown clip {name!r}; embedded clips: {', '.join(list_clips())}")
    return load_motion_npz(MOTIONS_DIR / f"{name}.npz", name=name)


def load_motion_npz(path: str | Path, name: str | None = None) -> Motion:
    """Read drape's own clip npz (poses, trans, fps) or an AMASS/SMPL-style npz.

    AMASS-style: `poses` (T, 72) or (T, 156) (first 72 values = 24 body joints),
    `trans` (T, 3), and `mocap_framerate` or `fps`. Never unpickles.
    """
    with np.load(path, allow_pickle=False) as z:
        if "poses" not in z:
            raise ValueError(f"{path}: no 'poses' array")
        poses = as_pose_array(z["poses"])
        trans = z["trans"] if "trans" in z else np.zeros((len(poses), 3))
        fps = 30.0
        for key in ("fps", "mocap_framerate", "mocap_frame_rate"):
            if key in z:
                fps = float(np.asarray(z[key]).reshape(-1)[0])
                break
    return Motion(poses, trans, fps, name or Path(path).stem)


def _slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation of (..., 4) quaternions; t broadcasts against (...)."""
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot).clip(-1.0, 1.0)
    theta = np.arccos(dot)
    sin = np.sin(theta)
    t = t[..., None]
    small = sin < 1e-6
    w0 = np.where(small, 1 - t, np.sin((1 - t) * theta) / np.where(small, 1, sin))
    w1 = np.where(small, t, np.sin(t * theta) / np.where(small, 1, sin))
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def resample(motion: Motion, fps: float) -> Motion:
    """Resample to a new frame rate: slerp for rotations, linear for translation."""
    T = motion.num_frames
    duration = (T - 1) / motion.fps
    n = int(round(duration * fps)) + 1
    src = np.linspace(0, T - 1, n) if T > 1 else np.zeros(1)
    i0 = np.floor(src).astype(int).clip(0, T - 1)
    i1 = (i0 + 1).clip(0, T - 1)
    t = src - i0
    q = axis_angle_to_quaternion(motion.poses)
    qi = _slerp(q[i0], q[i1], np.repeat(t[:, None], NUM_JOINTS, axis=1))
    trans = motion.trans[i0] * (1 - t[:, None]) + motion.trans[i1] * t[:, None]
    return Motion(quaternion_to_axis_angle(qi), trans, fps, motion.name)


def _yaw_quaternion(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(angle / 2), 0 * angle, np.sin(angle / 2), 0 * angle], axis=-1)


def heading(poses: np.ndarray) -> np.ndarray:
    """Yaw (rad, about +Y) of the root's forward axis (+Z at rest) per frame: (T, 24, 3) -> (T,)."""
    from drape.geometry.rotations import axis_angle_to_matrix

    fwd = axis_angle_to_matrix(poses[:, 0]) @ np.array([0.0, 0.0, 1.0])
    return np.arctan2(fwd[:, 0], fwd[:, 2])


def tile_cycle(motion: Motion, min_frames: int) -> Motion:
    """Repeat a cyclic clip (last frame = first frame of the next cycle) to at least min_frames.

    Each new cycle continues from where the last one ended: its root is turned by
    the cycle's net heading change and moved by its net horizontal displacement.
    """
    poses, trans = motion.poses.astype(np.float64), motion.trans.astype(np.float64)
    n = len(poses) - 1
    if n < 1 or len(poses) >= min_frames:
        return motion
    yaw = heading(poses)
    d_yaw = yaw[-1] - yaw[0]
    out_p: list[np.ndarray] = []
    out_t: list[np.ndarray] = []
    rot_k, origin = 0.0, trans[0].copy()
    q_root = axis_angle_to_quaternion(poses[:, 0])
    while sum(len(p) for p in out_p) < min_frames:
        c, s = np.cos(rot_k), np.sin(rot_k)
        r = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        rel = trans[:n] - trans[0]
        rel[:, 1] = 0
        t = origin + rel @ r.T
        t[:, 1] = trans[:n, 1]
        p = poses[:n].copy()
        p[:, 0] = quaternion_to_axis_angle(quaternion_multiply(_yaw_quaternion(np.full(n, rot_k)), q_root[:n]))
        out_p.append(p)
        out_t.append(t)
        step = trans[n] - trans[0]
        step[1] = 0
        origin = origin + r @ step
        rot_k += d_yaw
    return Motion(np.concatenate(out_p), np.concatenate(out_t), motion.fps, motion.name)
