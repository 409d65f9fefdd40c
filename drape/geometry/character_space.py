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


def motion_windows(joints: np.ndarray, root_position: np.ndarray, root_rotation: np.ndarray,
                   window: int) -> np.ndarray:
    """joints (T, 24, 3) world -> (T, window + 1, 24, 3) float32: frames t - window .. t (clamped at 0),
    each in the character space of frame t."""
    T = len(joints)
    idx = np.clip(np.arange(T)[:, None] + np.arange(-window, 1)[None, :], 0, None)  # (T, W + 1)
    w = (joints[idx] - root_position[:, None, None, :]).reshape(T, -1, 3)  # (T, (W + 1) * 24, 3)
    return np.matmul(w, root_rotation).reshape(T, window + 1, -1, 3).astype(np.float32)
