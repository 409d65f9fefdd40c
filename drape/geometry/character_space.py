"""The character space of a frame (Wang et al. 2019): the world translated by minus the root (pelvis)
position and rotated by the inverse of the root's global rotation. Pure numpy.

Shapes: poses (T, 24, 3) axis-angle rad, trans (T, 3) m, joints (T, 24, 3) m, root_position (T, 3) m,
root_rotation (T, 3, 3) (the pelvis' global rotation; columns are its axes in world space).
"""

from __future__ import annotations

import numpy as np

from drape.geometry.skeleton import forward_kinematics


def root_frames(poses: np.ndarray, trans: np.ndarray, rest_joints: np.ndarray, parents: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """poses (T, 24, 3) rad, trans (T, 3) m -> (joint positions (T, 24, 3), root position (T, 3),
    root rotation (T, 3, 3)), metres, world space."""
    tf, joints = forward_kinematics(poses, rest_joints, parents, trans)
    return joints, joints[:, 0], tf[:, 0, :3, :3]


def character_space_numpy(points: np.ndarray, root_position: np.ndarray, root_rotation: np.ndarray) -> np.ndarray:
    """points (T, ..., 3) world -> R_t^T (p - root_t) per frame t."""
    shape = points.shape
    p = points.reshape(shape[0], -1, 3) - root_position[:, None, :]
    return np.matmul(p, root_rotation).reshape(shape)  # row vectors: p R == (R^T p^T)^T


def world_space_numpy(points: np.ndarray, root_position: np.ndarray, root_rotation: np.ndarray) -> np.ndarray:
    """The inverse of `character_space_numpy`: points (T, ..., 3) -> R_t p + root_t."""
    shape = points.shape
    p = np.matmul(points.reshape(shape[0], -1, 3), np.swapaxes(root_rotation, 1, 2))
    return (p + root_position[:, None, :]).reshape(shape)


def frames_at(values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """values (T, ...) at frames 0..T-1, read at fractional frames `at` (any shape) -> at.shape + values.shape[1:],
    linearly between the two frames around each; `at` is clamped to [0, T - 1] (before the first frame, the first
    frame's values; past the last, the last's)."""
    T = len(values)
    at = np.clip(at, 0.0, T - 1)
    lo = np.floor(at).astype(np.int64)
    hi = np.minimum(lo + 1, T - 1)
    a = (at - lo).reshape(at.shape + (1,) * (values.ndim - 1))
    return values[lo] * (1.0 - a) + values[hi] * a


def motion_windows(joints: np.ndarray, root_position: np.ndarray, root_rotation: np.ndarray,
                   window: int, step: float = 1.0) -> np.ndarray:
    """joints (T, 24, 3) world -> (T, window + 1, 24, 3) float32: frames t - window .. t (clamped at 0),
    each in the character space of frame t.

    step: frames of this motion between two of the window's samples, the motion's fps over the fps the window
    was trained at (2.0: a 60 fps motion read by a 30 fps model): the samples lie at frames t - k * step, the
    joints linearly interpolated between frames, so a window spans the same seconds whatever the fps."""
    T = len(joints)
    if step == 1.0:
        idx = np.clip(np.arange(T)[:, None] + np.arange(-window, 1)[None, :], 0, None)  # (T, W + 1)
        picked = joints[idx]
    else:
        picked = frames_at(joints, np.arange(T)[:, None] + step * np.arange(-window, 1)[None, :])  # (T, W + 1, ..)
    w = (picked - root_position[:, None, None, :]).reshape(T, -1, 3)  # (T, (W + 1) * 24, 3)
    return np.matmul(w, root_rotation).reshape(T, window + 1, -1, 3).astype(np.float32)


MOTION_FEATURES = 78  # per frame: 69 joint rotations + gravity, velocity, angular velocity (3 each)


def motion_features(poses: np.ndarray, trans: np.ndarray, rest_joints: np.ndarray, parents: np.ndarray,
                    fps: float) -> np.ndarray:
    """A pose sequence as per-frame inputs of a sequence network -> (T, MOTION_FEATURES) float32.

    poses (T, 24, 3) or (T, 72) axis-angle rad, trans (T, 3) m, fps frames per second. Per frame t: the 23
    non-root joints' axis-angle rotations (69, rad); then in frame t's character space: the gravity direction
    (-Y world, unit), the root's velocity (m/s, backward difference; frame 0 takes frame 1's) and the root's
    angular velocity (axis-angle of R_{t-1}^T R_t times fps, rad/s, likewise). Invariant to where the body
    stands and which way it faces.
    """
    from drape.geometry.rotations import matrix_to_axis_angle

    poses = np.asarray(poses, np.float64).reshape(len(poses), 24, 3)
    _, root, rot = root_frames(poses, np.asarray(trans, np.float64), rest_joints, parents)
    gravity = np.einsum("tij,i->tj", rot, np.array([0.0, -1.0, 0.0]))
    velocity = np.zeros_like(root)
    spin = np.zeros_like(root)
    if len(poses) > 1:
        velocity[1:] = np.einsum("tij,ti->tj", rot[1:], np.diff(root, axis=0)) * fps
        spin[1:] = matrix_to_axis_angle(np.matmul(np.swapaxes(rot[:-1], 1, 2), rot[1:])) * fps
        velocity[0], spin[0] = velocity[1], spin[1]
    return np.concatenate([poses[:, 1:].reshape(len(poses), 69), gravity, velocity, spin], axis=1).astype(np.float32)
