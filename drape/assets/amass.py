"""AMASS / SMPL-family pose arrays (npz) onto drape's 24-joint skeleton, Z-up worlds turned Y-up.

Layouts taken (axis-angle radians, local rotations, SMPL joint order):
SMPL (T, 24, 3) / (T, 72): all 24 joints; SMPL-H (T, 52, 3) / (T, 156), as AMASS ships it, and
SMPL-X (T, 55, 3) / (T, 165): the 22 body joints, with drape's `left_hand` / `right_hand` (SMPL's
joints 22, 23, which SMPL-H and SMPL-X do not have: their joints from 22 on are fingers, or jaw and
eyes) at zero rotation; (T, 22, 3) / (T, 66), or AMASS's split `root_orient` (T, 3) + `pose_body`
(T, 63): the same 22. Quaternions and rotation matrices are refused with a message saying so.

AMASS worlds are Z-up; drape's is Y-up. `up="z"` turns the clip a quarter turn about +X (Z-up ->
Y-up): the root rotation is premultiplied by it and the pelvis path is rotated about the world origin.
`up=None` decides: a clip whose median body up axis (the root rotation applied to +Y) points along +Z
is Z-up, along +Y is Y-up; otherwise (a clip lying down) AMASS's keys (`mocap_framerate`,
`mocap_frame_rate`, `gender`, `betas`, `dmpls`) mean Z-up.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass

import numpy as np

from drape.assets.motion import MAX_FILE_FPS, MIN_FILE_FPS
from drape.geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle

AMASS_KEYS = ("mocap_framerate", "mocap_frame_rate", "gender", "betas", "dmpls")
FPS_KEYS = ("fps", "mocap_framerate", "mocap_frame_rate")
TRANS_KEYS = ("trans", "transl", "translation")  # AMASS / SMPL-X / drape's request name of the root translation
NPZ_MEMBERS = ("poses", *TRANS_KEYS, "root_orient", "pose_body", *FPS_KEYS)  # the members whose values are read
# AMASS's own members whose presence marks the file and whose values are never read (an AMASS gender is often a
# pickled object array: decoding it refused the whole file)
MARKER_KEYS = ("gender", "betas", "dmpls")
# joints per layout -> (name, joints kept from the start of the array)
LAYOUTS = {24: ("SMPL", 24), 52: ("SMPL-H", 22), 55: ("SMPL-X", 22), 22: ("SMPL body", 22)}
EXPECTED = ("axis-angle poses (T, 24, 3) or (T, 72) [SMPL], (T, 52, 3) or (T, 156) [SMPL-H, AMASS], "
            "(T, 55, 3) or (T, 165) [SMPL-X], (T, 22, 3) or (T, 66), or root_orient (T, 3) + pose_body (T, 63)")
# Z-up -> Y-up: a quarter turn about +X ((x, y, z) -> (x, z, -y))
Z_TO_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


class PoseArrayError(ValueError):
    """An npz whose arrays are not a pose sequence drape takes (the message says what was expected)."""


@dataclass(frozen=True)
class PoseClip:
    """poses (T, 24, 3) rad, trans (T, 3) m in the file's world, fps (None: the file has none),
    layout (e.g. "SMPL-H (T, 156)"), amass: the file carries AMASS's keys."""

    poses: np.ndarray
    trans: np.ndarray
    fps: float | None
    layout: str
    amass: bool


def _numbers(z: Mapping[str, np.ndarray], key: str) -> np.ndarray:
    a = np.asarray(z[key])
    if a.dtype.kind not in "iuf":
        raise PoseArrayError(f"'{key}' must hold real numbers, got dtype {a.dtype}")
    return a.astype(np.float64)


def to_pose24(p: np.ndarray, key: str = "poses") -> tuple[np.ndarray, str]:
    """A pose array of a layout in LAYOUTS -> (T, 24, 3) with the hands at zero where the layout has none."""
    shape = p.shape
    if p.ndim == 3 and shape[-1] == 4 or p.ndim == 2 and shape[1] % 4 == 0 and shape[1] // 4 in LAYOUTS:
        raise PoseArrayError(f"'{key}' {shape} looks like quaternions; expected {EXPECTED}")
    if p.ndim == 4 and shape[-2:] == (3, 3):
        raise PoseArrayError(f"'{key}' {shape} looks like rotation matrices; expected {EXPECTED}")
    if p.ndim == 2 and shape[1] % 3 == 0:
        p = p.reshape(len(p), shape[1] // 3, 3)  # not -1: numpy cannot infer it for zero frames
    if p.ndim != 3 or p.shape[2] != 3 or p.shape[1] not in LAYOUTS or len(p) < 1:
        raise PoseArrayError(f"'{key}' has shape {shape}; expected {EXPECTED}")
    name, keep = LAYOUTS[p.shape[1]]
    out = np.zeros((len(p), 24, 3))
    out[:, :keep] = p[:, :keep]
    return out, f"{name} {shape}"


def read_pose_arrays(z: Mapping[str, np.ndarray], names: Collection[str] = ()) -> PoseClip:
    """npz members (drape's clip npz, AMASS's, or any SMPL-family one) -> a PoseClip, not yet turned Y-up;
    names: every member the archive holds (those not read too: MARKER_KEYS), for telling AMASS files apart."""
    if "poses" in z:
        poses, layout = to_pose24(_numbers(z, "poses"))
    elif "root_orient" in z and "pose_body" in z:
        root, body = _numbers(z, "root_orient"), _numbers(z, "pose_body")
        if root.ndim != 2 or root.shape[1] != 3 or body.ndim != 2 or body.shape[1] != 63 or len(root) != len(body):
            raise PoseArrayError(f"expected root_orient (T, 3) and pose_body (T, 63), got {root.shape} and {body.shape}")
        poses, _ = to_pose24(np.concatenate([root, body], axis=1), "root_orient + pose_body")
        layout = f"AMASS root_orient + pose_body (T={len(root)})"
    else:
        raise PoseArrayError(f"no 'poses' array (nor 'root_orient' + 'pose_body'); expected {EXPECTED}")
    T = len(poses)
    given = [k for k in TRANS_KEYS if k in z]
    if len(given) > 1:  # which one is meant is anyone's guess
        raise PoseArrayError(f"the root translation is given as {' and '.join(map(repr, given))}: give one")
    if given:
        trans = _numbers(z, given[0])
        if trans.shape != (T, 3):
            raise PoseArrayError(f"'{given[0]}' must be ({T}, 3) to match the poses, got {trans.shape}")
    else:
        trans = np.zeros((T, 3))
    fps = None
    for key in FPS_KEYS:
        if key in z:
            v = _numbers(z, key).reshape(-1)
            # a BVH's bounds (Frame Time within [0.001, 10] s): lower rates overflow a resampled frame count
            if v.size != 1 or not MIN_FILE_FPS <= v[0] <= MAX_FILE_FPS:
                raise PoseArrayError(f"'{key}' must be one frame rate in [{MIN_FILE_FPS:g}, {MAX_FILE_FPS:g}], got {v[:3]}")
            fps = float(v[0])
            break
    if not (np.isfinite(poses).all() and np.isfinite(trans).all()):
        raise PoseArrayError("the poses or trans contain NaN or inf")
    return PoseClip(poses, trans, fps, layout, any(k in z or k in names for k in AMASS_KEYS))


def detect_up(clip: PoseClip) -> tuple[str, str]:
    """("y" or "z", why) for a clip's world up axis (see the module docstring)."""
    up = np.median(axis_angle_to_matrix(clip.poses[:, 0])[..., :, 1], axis=0)  # the body's +Y in the world
    if up[2] > 0.5 and up[2] > abs(up[1]):
        return "z", f"the body's up axis points along +Z (median {up.round(2).tolist()})"
    if up[1] > 0.5:
        return "y", f"the body's up axis points along +Y (median {up.round(2).tolist()})"
    if clip.amass:
        return "z", "AMASS keys (mocap_framerate, gender, betas) and no clear up axis"
    return "y", "no AMASS keys and no clear up axis"


def z_up_to_y_up(poses: np.ndarray, trans: np.ndarray, pelvis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turn a Z-up clip Y-up: root rotation premultiplied by Z_TO_Y; the pelvis (rest `pelvis` + trans)
    rotated about the world origin. -> (poses, trans)."""
    poses = np.array(poses, dtype=np.float64)
    poses[:, 0] = matrix_to_axis_angle(Z_TO_Y @ axis_angle_to_matrix(poses[:, 0]))
    pelvis = np.asarray(pelvis, dtype=np.float64)
    return poses, (np.asarray(trans, dtype=np.float64) + pelvis) @ Z_TO_Y.T - pelvis
