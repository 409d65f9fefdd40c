"""Motions: a pose sequence on the 24-joint skeleton, its loaders, time operations, floor contact and
the file importer behind `drape motions import` and the service's `motion_file` (docs/motion_import.md).

poses: (T, 24, 3) float32 axis-angle radians (local, relative to the T-pose rest);
trans: (T, 3) float32 metres (root translation added to every joint); fps: frames/s.
Embedded clips live at drape/assets/motions/<name>.npz with exactly those three keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drape.assets.body import Body
from drape.geometry.rotations import (
    axis_angle_to_quaternion,
    quaternion_multiply,
    quaternion_to_axis_angle,
)
from drape.geometry.skeleton import NUM_JOINTS, as_pose_array

if TYPE_CHECKING:
    from drape.assets.motion_flips import Flip

MOTIONS_DIR = Path(__file__).parent / "motions"
# bounds on a motion's values, for files and requests alike: far beyond any real motion, far below where posing
# in float32 overflows (a value of 1e20 squares past float32's range; 1e300 past float64's) to NaN frames
MAX_POSE_RAD = 1e4  # |axis-angle value|, radians
MAX_TRANSLATION_M = 1e4  # |root translation|, metres (10 km)
MIN_FILE_FPS, MAX_FILE_FPS = 0.1, 1000.0  # a motion file's frame rate (a BVH's Frame Time: 10 s to 1 ms), or --fps


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

    def save(self, path: str | Path) -> Path:
        """Write the clip npz, making its folder as `drape outfits` makes a mesh's; -> the file written (numpy
        adds .npz to a path without it)."""
        out = Path(path)
        out = out if out.suffix.lower() == ".npz" else out.with_name(out.name + ".npz")
        out.parent.mkdir(parents=True, exist_ok=True)
        with open(out, "wb") as f:  # a file object: numpy would add .npz to "take.NPZ" too
            np.savez_compressed(f, poses=self.poses, trans=self.trans, fps=np.float32(self.fps))
        return out


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
    """Read drape's own clip npz: `poses` (T, 24, 3) or (T, 72) rad, Y-up, `trans` (T, 3) m, `fps` (what
    `drape motions import` and Motion.save write). Never unpickles.

    An AMASS file (its keys: `mocap_framerate`, `gender`, `betas`, ...) or an SMPL-H/-X-wide pose array is a
    ValueError pointing at `drape motions import`, which turns it Y-up, maps its layout's joints (SMPL-H's
    values 66-71 are left-hand fingers, not SMPL's hands) and puts its feet on the floor; read here as they
    are, such a clip was simulated lying on its side.

    A file that is not an npz (text, empty, truncated, one .npy array), members that disagree (trans and poses
    of different lengths, NaN, a rate <= 0) or no frames: a ValueError naming the file.
    """
    import zipfile

    try:
        motion = _read_motion_npz(path, name)
    except (EOFError, zipfile.BadZipFile) as exc:  # empty or truncated
        raise ValueError(f"{path}: not a readable npz file ({exc})") from exc
    except ValueError as exc:
        if str(exc).startswith(f"{path}: "):
            raise
        raise ValueError(f"{path}: {exc}") from exc
    if motion.num_frames == 0:
        raise ValueError(f"{path}: the clip has no frames")
    return motion


def _read_motion_npz(path: str | Path, name: str | None) -> Motion:
    """`load_motion_npz` without its last checks: ValueErrors that may not name the file yet."""
    from drape.assets.amass import AMASS_KEYS

    try:
        archive = np.load(path, allow_pickle=False)
    except ValueError as exc:  # neither the npy nor the zip magic: numpy's message is about pickles
        raise ValueError(f"{path}: not an npz file (a zip of .npy arrays)") from exc
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: holds one .npy array, not an npz of poses, trans and fps")
    with archive as z:
        if "poses" not in z:
            raise ValueError(f"{path}: no 'poses' array")
        raw = z["poses"]
        amass_keys = [k for k in AMASS_KEYS if k in z]
        if amass_keys or not (raw.ndim == 3 and raw.shape[1:] == (NUM_JOINTS, 3)
                              or raw.ndim == 2 and raw.shape[1] == 3 * NUM_JOINTS):
            why = f"AMASS keys {amass_keys}" if amass_keys else f"poses {raw.shape}"
            raise ValueError(f"{path}: not a drape clip ({why}); convert it first: "
                             f"drape motions import {path} --out CLIP.npz (up axis, joint layout, floor, fps)")
        poses = as_pose_array(raw)
        trans = z["trans"] if "trans" in z else np.zeros((len(poses), 3))
        fps = 30.0
        for key in ("fps", "mocap_framerate", "mocap_frame_rate"):
            if key in z:
                given = np.asarray(z[key]).reshape(-1)
                if given.size != 1 or given.dtype.kind not in "fiu":
                    raise ValueError(f"{path}: '{key}' must be one number, got {given.shape} {given.dtype}")
                fps = float(given[0])
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


def resampled_count(num_frames: int, src_fps: float, fps: float) -> int:
    """Frames `resample` makes from num_frames at src_fps: one every 1/fps s from the first frame, within
    the clip (the last may fall short of the clip's end by less than one new frame)."""
    if num_frames <= 1:
        return num_frames
    return int(np.floor((num_frames - 1) * fps / src_fps + 1e-6)) + 1


def resample(motion: Motion, fps: float) -> Motion:
    """Resample to a new frame rate: new frame k is the source at time k / fps, rotations interpolated
    with slerp (per joint, shortest arc), translation linearly; no frame is dropped or repeated."""
    T = motion.num_frames
    n = resampled_count(T, motion.fps, fps)
    # one frame (an fps so low no second frame fits) is the first: the step, motion.fps / fps, may overflow to inf
    step = motion.fps / fps if n > 1 else 0.0
    src = np.minimum(np.arange(n) * step, T - 1)
    i0 = np.floor(src + 1e-9).astype(int).clip(0, T - 1)
    i1 = (i0 + 1).clip(0, T - 1)
    t = np.clip(src - i0, 0.0, 1.0)
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


# ---- floor contact ------------------------------------------------------------------------------

FOOT_JOINTS = ("left_ankle", "right_ankle", "left_foot", "right_foot")
FLOOR_SAMPLES = 120  # frames posed (evenly spread) to estimate a clip's floor


def foot_heights(motion: Motion, body: Body, chunk: int = 512) -> np.ndarray:
    """Lowest foot point per frame (T,) metres: bench/foot_floor.py's measure (deepmimic.foot_heights:
    the vertices whose strongest skin weight is an ankle or foot joint), posing only those, in chunks."""
    from drape.geometry.lbs import pose_mesh
    from drape.geometry.skeleton import JOINT_INDEX

    mask = np.isin(body.weights.argmax(axis=1), [JOINT_INDEX[n] for n in FOOT_JOINTS])
    v, w = body.vertices[mask], body.weights[mask]
    return np.concatenate([
        pose_mesh(v, w, body.joints, motion.poses[s:s + chunk], motion.trans[s:s + chunk], body.parents)[..., 1].min(1)
        for s in range(0, motion.num_frames, chunk)])


def floor_offset(motion: Motion, body: Body, samples: int = FLOOR_SAMPLES) -> float:
    """A clip's floor height (m): the median over frames (at most `samples`, evenly spread) of the body's
    lowest point per frame, posed with the whole body mesh."""
    idx = np.unique(np.linspace(0, motion.num_frames - 1, min(samples, motion.num_frames)).round().astype(int))
    lowest = np.concatenate([body.pose(motion.poses[idx[s:s + 32]], motion.trans[idx[s:s + 32]])[..., 1].min(1)
                             for s in range(0, len(idx), 32)])
    return float(np.median(lowest))


@dataclass(frozen=True)
class FloorFix:
    """A clip put on the floor: the height subtracted from trans (m) and bench/foot_floor.py's foot-floor
    error (median over frames of |lowest foot point|, m) before and after."""

    motion: Motion
    shift: float
    before: float
    after: float


def put_on_floor(motion: Motion, body: Body) -> FloorFix:
    """Shift the clip vertically so the body's lowest point sits on y = 0 (median over frames)."""
    feet = foot_heights(motion, body)
    shift = floor_offset(motion, body)
    trans = motion.trans.astype(np.float64)
    trans[:, 1] -= shift
    return FloorFix(Motion(motion.poses, trans, motion.fps, motion.name), shift,
                    float(np.median(np.abs(feet))), float(np.median(np.abs(feet - shift))))


# ---- importing files (`drape motions import`, the service's motion_file) -----------------------

class MotionFileError(ValueError):
    """A motion file drape cannot import; the message says what was expected."""


class MotionTooLong(MotionFileError):
    """A motion file with more frames than a limit allows."""


@dataclass(frozen=True)
class ImportedMotion:
    """An imported clip and what the importer did to it."""

    motion: Motion
    kind: str  # "bvh" or "npz"
    layout: str
    source_frames: int
    source_fps: float
    up: str
    up_reason: str
    dropped_tpose: bool
    floor: FloorFix | None
    flips: tuple[Flip, ...] = ()  # rotation flips repaired (source frames), drape.assets.motion_flips
    warnings: tuple[str, ...] = ()  # what looks wrong (an `up` the file contradicts; feet left off the floor)

    def summary(self) -> str:
        m = self.motion
        lines = [f"{self.kind}: {self.layout}, {self.source_frames} frames at {self.source_fps:g} fps, "
                 f"{self.up.upper()}-up ({self.up_reason})"]
        if self.dropped_tpose:
            lines.append("dropped frame 0: the T-pose frame the CMU BVH conversion adds")
        if self.flips:
            lines.append(f"repaired {len(self.flips)} rotation flip(s), source frames slerped across: "
                         + "; ".join(f.describe() for f in self.flips))
        if m.fps != self.source_fps:
            lines.append(f"resampled to {m.fps:g} fps (slerp): {m.num_frames} frames")
        if self.floor is not None:
            f = self.floor
            moved = f"down {f.shift * 1e3:.1f} mm" if f.shift >= 0 else f"up {-f.shift * 1e3:.1f} mm"
            lines.append(f"floor: lowest body point moved {moved}; foot-floor error (median "
                         f"|lowest foot point|) {f.before * 1e3:.1f} mm before, {f.after * 1e3:.1f} mm after")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def sniff_motion_file(data: bytes) -> str:
    """"bvh" or "npz" from a file's first bytes; MotionFileError for anything else."""
    if data[:4] == b"PK\x03\x04":
        return "npz"
    if data.lstrip()[:9].upper() == b"HIERARCHY":
        return "bvh"
    raise MotionFileError("expected a BVH file (text starting with HIERARCHY) or an npz (a zip of .npy arrays)")


def import_motion(data: bytes, body: Body, *, fps: float | None = None, up: str | None = None,
                  floor: bool = True, flips: bool = True, name: str = "", max_frames: int | None = None,
                  max_source_frames: int | None = None, max_decoded_bytes: int | None = None) -> ImportedMotion:
    """A motion file's bytes (CMU-named BVH, or an npz: drape's clip, AMASS, SMPL-family poses) -> a clip
    on `body`: retargeted (BVH) or converted (npz), turned Y-up (`up`: "y", "z", None = detect), the
    added T-pose frame of raw CMU BVH dropped, rotation flips repaired (`flips`; drape.assets.motion_flips),
    resampled to `fps` (None: the file's), put on the floor.

    Limits (None: none): max_source_frames bounds the file's frames before its numbers are worked on,
    max_frames the frames after resampling (MotionTooLong), max_decoded_bytes an npz's arrays.
    MotionFileError (a ValueError) names what was expected for anything else.
    """
    if up not in (None, "y", "z"):
        raise MotionFileError(f"up must be 'y' or 'z', got {up!r}")
    if fps is not None and not 0 < fps <= 1000:
        raise MotionFileError(f"fps must be in (0, 1000], got {fps}")
    data = data.removeprefix(b"\xef\xbb\xbf")  # a UTF-8 byte order mark (Windows editors write one)
    kind = sniff_motion_file(data)
    if kind == "bvh":
        return _import_bvh(data, body, fps, up, floor, flips, name, max_frames, max_source_frames)
    return _import_npz(data, body, fps, up, floor, flips, name, max_frames, max_source_frames, max_decoded_bytes)


def _check_frames(n: int, limit: int | None, what: str) -> None:
    if limit is not None and n > limit:
        raise MotionTooLong(f"{n} frames {what} exceed the limit of {limit}")


def _finish(motion: Motion, body: Body, fps: float | None, floor: bool,
            flips: bool) -> tuple[Motion, FloorFix | None, tuple[Flip, ...]]:
    from drape.assets.motion_flips import repair_flips

    motion, found = repair_flips(motion) if flips else (motion, [])
    if fps is not None and fps != motion.fps:
        motion = resample(motion, fps)
    fix = put_on_floor(motion, body) if floor else None
    return (fix.motion if fix is not None else motion), fix, tuple(found)


FLOOR_WARNING_M = 0.1  # a foot-floor error left after the floor step above this (m) is worth a warning (real CMU: <= 47 mm)


def _warnings(up: str | None, detected: tuple[str, str], clear: bool, fix: FloorFix | None) -> tuple[str, ...]:
    """What an import should tell its user: an `up` that the file's own skeleton contradicts (`detected`, when
    `clear`: a measured direction, not a default), and feet the floor step left far from the floor."""
    out = []
    if up is not None and clear and detected[0] != up:
        out.append(f"{detected[1]}: the file looks {detected[0].upper()}-up, not {up.upper()}-up as asked (the "
                   f"body may lie on its side; leave out up to detect it)")
    if fix is not None and fix.after > FLOOR_WARNING_M:
        out.append(f"the feet stay {fix.after * 1e3:.0f} mm from the floor (median) after the floor step: is the "
                   f"up axis right?")
    return tuple(out)


def _import_bvh(data: bytes, body: Body, fps: float | None, up: str | None, floor: bool, flips: bool, name: str,
                max_frames: int | None, max_source_frames: int | None) -> ImportedMotion:
    from dataclasses import replace

    from drape.assets import bvh

    text = data.decode("latin-1")
    try:
        header = bvh.read_header(text)
        _check_frames(header.num_frames, max_source_frames, "in the file")
        clip = bvh.parse_bvh(text)
        dropped = bvh.has_added_tpose(clip)
        if dropped:
            clip = replace(clip, values=clip.values[1:])
        _check_frames(clip.num_frames if fps is None else resampled_count(clip.num_frames, clip.fps, fps),
                      max_frames, f"at {fps or clip.fps:g} fps")
        chosen, why = (up, "as asked") if up is not None else bvh.detect_up(clip)
        motion = bvh.retarget(clip, body, name, "", up=chosen)
    except bvh.BvhTooLong as exc:
        raise MotionTooLong(str(exc)) from exc
    except bvh.BvhError as exc:
        raise MotionFileError(str(exc)) from exc
    out, fix, found = _finish(motion, body, fps, floor, flips)
    detected = bvh.detect_up(clip)
    return ImportedMotion(out, "bvh", f"CMU-named BVH, {len(clip.names)} joints", header.num_frames, clip.fps,
                          chosen, why, dropped, fix, found,
                          _warnings(up, detected, detected[1] != bvh.DEFAULT_UP_REASON, fix))


def _import_npz(data: bytes, body: Body, fps: float | None, up: str | None, floor: bool, flips: bool, name: str,
                max_frames: int | None, max_source_frames: int | None,
                max_decoded_bytes: int | None) -> ImportedMotion:
    import io
    import zipfile

    from drape.assets import amass
    from drape.schemas.binary import NpzTooLarge, decode_npz

    try:
        z = decode_npz(data, amass.NPZ_MEMBERS, max_bytes=max_decoded_bytes)
        with zipfile.ZipFile(io.BytesIO(data)) as archive:  # read by decode_npz already: its names, not the values
            names = {n[:-len(".npy")] for n in archive.namelist() if n.endswith(".npy")}
    except NpzTooLarge as exc:
        raise MotionTooLong(str(exc)) from exc
    except (ValueError, zipfile.BadZipFile) as exc:
        raise MotionFileError(f"not a readable npz ({exc})") from exc
    # the frames from the pose array's length first: read_pose_arrays widens it to float64 and copies it
    rows = next((z[k].shape[0] for k in ("poses", "root_orient") if k in z and z[k].ndim), None)
    if rows is not None:
        _check_frames(rows, max_source_frames, "in the file")
    try:
        clip = amass.read_pose_arrays(z, names)
    except amass.PoseArrayError as exc:
        raise MotionFileError(str(exc)) from exc
    if np.abs(clip.poses).max() > MAX_POSE_RAD:
        raise MotionFileError(f"the poses hold axis-angle values beyond {MAX_POSE_RAD:g} radians")
    if np.abs(clip.trans).max() > MAX_TRANSLATION_M:
        raise MotionFileError(f"'trans' moves the root beyond {MAX_TRANSLATION_M:g} m")
    T = len(clip.poses)
    src_fps = clip.fps if clip.fps is not None else (fps or 30.0)
    _check_frames(T, max_source_frames, "in the file")
    _check_frames(T if fps is None else resampled_count(T, src_fps, fps), max_frames, f"at {fps or src_fps:g} fps")
    chosen, why = (up, "as asked") if up is not None else amass.detect_up(clip)
    poses, trans = clip.poses, clip.trans
    if chosen == "z":
        poses, trans = amass.z_up_to_y_up(poses, trans, body.joints[0])
    motion = Motion(poses, trans, src_fps, name)
    out, fix, found = _finish(motion, body, fps, floor, flips)
    layout = clip.layout + ("" if clip.fps is not None else f", no frame rate in the file: {src_fps:g} fps assumed")
    detected = amass.detect_up(clip)
    return ImportedMotion(out, "npz", layout, T, src_fps, chosen, why, False, fix, found,
                          _warnings(up, detected, "no clear up axis" not in detected[1], fix))
