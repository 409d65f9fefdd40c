"""Import BVH motion capture with CMU joint names onto drape's 24-joint skeleton.

Parsing is drape's own (numpy only, bounded: it serves uploads too): HIERARCHY with ROOT / JOINT /
End Site / OFFSET / CHANNELS (any order of X/Y/Z rotation and position channels), then MOTION with
`Frames:` and `Frame Time:`; the number of values must be exactly frames x channels. Euler channels
compose in the order written (the BVH convention: `Zrotation Yrotation Xrotation` is Rz Ry Rx).

Retargeting carries each mapped bone's global rotation over, bridged from the BVH's own rest pose to
drape's T-pose: for a joint j with a child c, the bridge is the smallest rotation taking drape's rest
bone direction (c - j) to the BVH's. Real CMU files have zero-length segments (Hips -> LowerBack,
Spine1 -> Neck, Spine1 -> LeftShoulder, Hand -> FingerBase): a bone's BVH direction is measured to the
next joint that is not coincident (Spine1 -> Neck1, Hand -> HandIndex1) and follows the rotation of the
joint that segment hangs from (Neck, FingerBase); drape's neck and hand joints then sit at Neck1 and
HandIndex1 (`map_joints`). Every drape bone then points where its BVH segment points, frame by frame.
The 7 extra CMU bones (hip joints, Neck1, thumbs, finger tips) are absorbed into the chain. Y-up files
(Z-up ones with up="z"); any unit works (root motion is scaled by the leg-length ratio). Floor contact, the added T-pose frame
of raw CMU clips and frame-rate conversion are `drape.assets.motion.import_motion`'s steps.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drape.assets.amass import Z_TO_Y
from drape.assets.body import Body
from drape.assets.motion import MAX_FILE_FPS, MAX_TRANSLATION_M, MIN_FILE_FPS, Motion
from drape.geometry.rotations import matrix_to_axis_angle, rotation_between
from drape.geometry.skeleton import CMU_TO_SMPL, JOINT_INDEX, JOINT_NAMES, PARENTS

MAX_JOINTS = 256
MAX_DEPTH = 128
MAX_HEADER_CHARS = 2**20  # the HIERARCHY text (CMU's 31 joints take ~6 kB)
CHUNK_FRAMES = 1024  # frames retargeted at once (bounds the temporary rotation matrices)

# the child whose direction defines each joint's bone (leaf joints borrow their parent's bridge)
_BONE_CHILD = {
    "left_hip": "left_knee", "right_hip": "right_knee", "left_knee": "left_ankle",
    "right_knee": "right_ankle", "left_ankle": "left_foot", "right_ankle": "right_foot",
    "spine1": "spine2", "spine2": "spine3", "spine3": "neck", "neck": "head",
    "left_collar": "left_shoulder", "right_collar": "right_shoulder",
    "left_shoulder": "left_elbow", "right_shoulder": "right_elbow",
    "left_elbow": "left_wrist", "right_elbow": "right_wrist",
    "left_wrist": "left_hand", "right_wrist": "right_hand",
}
_AXES = {"X": 0, "Y": 1, "Z": 2}
_CHANNEL = re.compile(r"^([XYZ])(rotation|position)$", re.IGNORECASE)
# a count (Frames, CHANNELS): ASCII digits only (str.isdigit takes '²', which int() refuses) and at most 18 of
# them (int() refuses more than 4300; every limit refuses far fewer)
_WHOLE = re.compile(r"[0-9]{1,18}")


class BvhError(ValueError):
    """A BVH file drape cannot read or retarget (the message says what was expected)."""


class BvhTooLong(BvhError):
    """A BVH file that declares more frames than drape reads (more than 18 digits, or over `max_frames`)."""


@dataclass(frozen=True)
class BvhClip:
    """A parsed BVH: joints in file order (parents[j] < j, root -1), offsets (J, 3) in file units,
    end_sites {joint: first End Site offset}, channels per joint ("Xrotation", ...), frame_time s,
    values (T, C) float64 (C = all channels, in file order)."""

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: dict[int, np.ndarray]
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    values: np.ndarray

    @property
    def num_frames(self) -> int:
        return len(self.values)

    @property
    def fps(self) -> float:
        return _fps(self.frame_time)


def _fps(frame_time: float) -> float:
    """Frames per second; a rate within 0.1% of a whole number is that number (files print 0.0083333 s)."""
    fps = 1.0 / frame_time
    return float(round(fps)) if abs(fps - round(fps)) < 1e-3 * fps else fps


@dataclass(frozen=True)
class BvhHeader:
    """What a BVH declares before its numbers: joints, channels, frame count, frame time, and where the
    numbers start in the text."""

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: dict[int, np.ndarray]
    channels: tuple[tuple[str, ...], ...]
    num_frames: int
    frame_time: float
    data_start: int

    @property
    def fps(self) -> float:
        return _fps(self.frame_time)


def _number(tok: str, what: str) -> float:
    try:
        v = float(tok)
    except ValueError:
        raise BvhError(f"expected a number for {what}, got {tok[:40]!r}") from None
    if not np.isfinite(v):
        raise BvhError(f"{what} is not finite")
    return v


def read_header(text: str) -> BvhHeader:
    """Parse a BVH's HIERARCHY and MOTION header lines (cheap; the numbers are read by `parse_bvh`)."""
    m = re.search(r"\bMOTION\b", text)
    if m is None or not re.match(r"\s*HIERARCHY\b", text, re.IGNORECASE):
        raise BvhError("not a BVH file: expected 'HIERARCHY' ... 'MOTION'")
    if m.start() > MAX_HEADER_CHARS:
        raise BvhError(f"the HIERARCHY is longer than {MAX_HEADER_CHARS} characters")
    toks = text[: m.start()].split()[1:]
    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray | None] = []
    channels: list[tuple[str, ...]] = []
    end_sites: dict[int, np.ndarray] = {}
    stack: list[int] = []  # open joints; -2 marks an open End Site
    i = 0

    def need(k: int) -> list[str]:
        if i + k > len(toks):
            raise BvhError("the HIERARCHY ends early")
        return toks[i:i + k]

    while i < len(toks):
        tok = toks[i]
        key = tok.upper()
        if key in ("ROOT", "JOINT"):
            (name,) = need(2)[1:]
            if (key == "ROOT") != (not names):
                raise BvhError("expected one ROOT, first" if key == "JOINT" else "more than one ROOT")
            if len(names) >= MAX_JOINTS:
                raise BvhError(f"more than {MAX_JOINTS} joints")
            if need(3)[2] != "{":
                raise BvhError(f"expected '{{' after {key} {name}")
            if stack and stack[-1] == -2:
                raise BvhError(f"JOINT {name} inside an End Site")
            names.append(name)
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            channels.append(())
            stack.append(len(names) - 1)
            if len(stack) > MAX_DEPTH:
                raise BvhError(f"joints nested deeper than {MAX_DEPTH}")
            i += 3
        elif key == "END":
            if not stack or stack[-1] < 0 or need(3)[2] != "{":
                raise BvhError("misplaced 'End Site'")
            stack.append(-2)
            end_sites.setdefault(stack[-2], np.zeros(3))
            i += 3
        elif key == "OFFSET":
            vals = np.array([_number(t, "OFFSET") for t in need(4)[1:]])
            if not stack:
                raise BvhError("OFFSET outside a joint")
            if stack[-1] == -2:
                end_sites[stack[-2]] = vals
            else:
                offsets[stack[-1]] = vals
            i += 4
        elif key == "CHANNELS":
            if not stack or stack[-1] < 0:
                raise BvhError("CHANNELS outside a joint")
            n_tok = need(2)[1]
            if not _WHOLE.fullmatch(n_tok) or int(n_tok) > 6:
                raise BvhError(f"expected 0 to 6 CHANNELS, got {n_tok[:20]!r}")
            n = int(n_tok)
            chans = tuple(need(2 + n)[2:])
            for c in chans:
                if not _CHANNEL.match(c):
                    raise BvhError(f"unknown channel {c[:40]!r}: expected X/Y/Z rotation or position")
            if len({c.lower() for c in chans}) != n:
                raise BvhError(f"repeated channel in {' '.join(chans)}")
            channels[stack[-1]] = chans
            i += 2 + n
        elif tok == "}":
            if not stack:
                raise BvhError("unbalanced '}' in the HIERARCHY")
            stack.pop()
            i += 1
        else:
            raise BvhError(f"unexpected {tok[:40]!r} in the HIERARCHY")
    if stack or not names:
        raise BvhError("the HIERARCHY has no ROOT or unclosed braces")
    missing = [names[j] for j, o in enumerate(offsets) if o is None]
    if missing:
        raise BvhError(f"joints without OFFSET: {missing[:5]}")
    head = re.match(r"\s*MOTION\s+Frames:\s*(\S+)\s+Frame\s+Time:\s*(\S+)", text[m.start():], re.IGNORECASE)
    if head is None:
        raise BvhError("expected 'Frames: N' and 'Frame Time: t' after MOTION")
    count = head.group(1)
    digits = count.lstrip("0") if count.isascii() and count.isdigit() else ""
    if len(digits) > 18:
        raise BvhTooLong(f"'Frames:' declares a {len(digits)}-digit number of frames, more than any limit allows")
    if not digits:  # not ASCII digits, or zero
        raise BvhError(f"expected a positive whole number of frames, got {count[:20]!r}")
    frame_time = _number(head.group(2), "Frame Time")
    if not 1.0 / MAX_FILE_FPS <= frame_time <= 1.0 / MIN_FILE_FPS:
        raise BvhError(f"Frame Time must be within [{1.0 / MAX_FILE_FPS:g}, {1.0 / MIN_FILE_FPS:g}] s "
                       f"({MAX_FILE_FPS:g} fps to {MIN_FILE_FPS:g} fps), got {frame_time:g}")
    return BvhHeader(tuple(names), np.array(parents, dtype=np.int64),
                     np.array([o for o in offsets if o is not None], dtype=np.float64), end_sites,
                     tuple(channels), int(digits), frame_time, m.start() + head.end())


def parse_bvh(text: str, max_frames: int | None = None) -> BvhClip:
    """Parse BVH text; more than `max_frames` frames (declared) is a BvhError before the numbers are read."""
    h = read_header(text)
    if max_frames is not None and h.num_frames > max_frames:
        raise BvhTooLong(f"{h.num_frames} frames exceed the limit of {max_frames}")
    n_chan = sum(len(c) for c in h.channels)
    want = h.num_frames * n_chan
    body = text[h.data_start:]
    if len(body) > 64 * want + 4096:  # no number takes 64 characters: the text holds more than declared
        raise BvhError(f"the MOTION is longer than {h.num_frames} frames x {n_chan} channels of numbers")
    try:
        values = np.fromstring(body, dtype=np.float64, sep=" ") if body.strip() else np.zeros(0)
    except ValueError:
        raise BvhError("the MOTION holds something other than numbers") from None
    if len(values) != want:
        raise BvhError(f"{h.num_frames} frames x {n_chan} channels need {want} numbers, "
                       f"the MOTION has {len(values)}")
    if not np.isfinite(values).all():
        raise BvhError("the MOTION contains NaN or inf")
    return BvhClip(h.names, h.parents, h.offsets, h.end_sites, h.channels, h.frame_time,
                   values.reshape(h.num_frames, n_chan) if n_chan else np.zeros((h.num_frames, 0)))


def read_bvh(path: str | Path, max_frames: int | None = None) -> BvhClip:
    return parse_bvh(Path(path).read_text(encoding="utf-8-sig", errors="replace"), max_frames)


def _axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """(T,) radians -> (T, 3, 3) rotation about one coordinate axis."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros(angle.shape + (3, 3))
    a, b = (axis + 1) % 3, (axis + 2) % 3
    m[..., axis, axis] = 1.0
    m[..., a, a] = c
    m[..., b, b] = c
    m[..., b, a] = s
    m[..., a, b] = -s
    return m


def local_transforms(clip: BvhClip, frames: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (T, J, 3, 3) and local positions (T, J, 3) of the frames `frames`: Euler channels
    composed in the order written, position channels replacing the OFFSET's components."""
    vals = clip.values[frames]
    T, J = len(vals), len(clip.names)
    rot = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
    pos = np.broadcast_to(clip.offsets, (T, J, 3)).copy()
    col = 0
    for j, chans in enumerate(clip.channels):
        for c in chans:
            axis, kind = _AXES[c[0].upper()], c[1:].lower()
            if kind == "rotation":
                rot[:, j] = rot[:, j] @ _axis_rotation(axis, np.deg2rad(vals[:, col]))
            else:
                pos[:, j, axis] = vals[:, col]
            col += 1
    return rot, pos


def global_fk(clip: BvhClip, frames: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations (T, J, 3, 3) and positions (T, J, 3) in file units."""
    rot, pos = local_transforms(clip, frames)
    grot, gpos = np.empty_like(rot), np.empty_like(pos)
    for j, p in enumerate(clip.parents):
        if p < 0:
            grot[:, j], gpos[:, j] = rot[:, j], pos[:, j]
        else:
            grot[:, j] = grot[:, p] @ rot[:, j]
            gpos[:, j] = gpos[:, p] + np.einsum("tij,tj->ti", grot[:, p], pos[:, j])
    return grot, gpos


def rest_positions(clip: BvhClip) -> np.ndarray:
    """Rest joint positions (J, 3) relative to the root, from the OFFSETs."""
    rest = np.zeros((len(clip.names), 3))
    for j, p in enumerate(clip.parents):
        if p >= 0:
            rest[j] = rest[p] + clip.offsets[j]
    return rest


def _check_cmu(clip: BvhClip, source: str) -> dict[str, int]:
    pre = f"{source}: " if source else ""
    col = {n: i for i, n in enumerate(clip.names)}
    missing = [n for n in CMU_TO_SMPL if n not in col]
    if missing:
        found = ", ".join(n[:40] for n in clip.names[:8]) + (", ..." if len(clip.names) > 8 else "")
        raise BvhError(f"{pre}expected a CMU-named skeleton ({', '.join(list(CMU_TO_SMPL)[:6])}, ...); "
                       f"lacks {len(missing)} of its {len(CMU_TO_SMPL)} joints ({', '.join(missing[:6])}"
                       f"{', ...' if len(missing) > 6 else ''}); the file has {found}")
    root = int(np.flatnonzero(clip.parents < 0)[0])
    if clip.names[root] != "Hips":
        raise BvhError(f"{pre}expected the root joint 'Hips', got {clip.names[root][:40]!r}")
    for cmu, smpl in CMU_TO_SMPL.items():
        if smpl == "pelvis":
            continue
        want = JOINT_NAMES[PARENTS[JOINT_INDEX[smpl]]]
        p = int(clip.parents[col[cmu]])
        while p >= 0 and CMU_TO_SMPL.get(clip.names[p]) is None:
            p = int(clip.parents[p])
        if p < 0 or CMU_TO_SMPL[clip.names[p]] != want:
            raise BvhError(f"{pre}joint {cmu} should hang below the joint mapped to {want}")
    return col


def _path(parents: np.ndarray, kids: dict[int, list[int]], start: int, target: int | None) -> list[int]:
    """BVH joints after `start` down to its descendant `target`, or down first children when target is None."""
    path: list[int] = []
    if target is None:
        k = start
        while kids.get(k):
            k = kids[k][0]
            path.append(k)
        return path
    k = target
    while k >= 0 and k != start:
        path.append(k)
        k = int(parents[k])
    return path[::-1] if k == start else []


@dataclass(frozen=True)
class JointMap:
    """How drape's 24 joints read a BVH: anchor[j] is the BVH joint at drape joint j's place, source[j] the
    BVH joint whose global rotation turns drape joint j's bone, bridge[j] (3, 3) drape's rest bone
    direction to the BVH's (global rotation of j = global rotation of source[j] @ bridge[j])."""

    anchor: np.ndarray
    source: np.ndarray
    bridge: np.ndarray


def map_joints(clip: BvhClip, rest: np.ndarray, ours: np.ndarray, bvh_of: dict[str, int], tol: float) -> JointMap:
    """Anchors, rotation sources and bridges, past the zero-length segments of real CMU files.

    A mapped BVH joint coincident (within `tol`) with its drape parent's anchor is anchored at the first
    unmapped joint down its chain that is not (Neck -> Neck1, FingerBase -> HandIndex1). A bone's BVH
    direction runs from its anchor to its child's anchor, and turns with the parent of the first joint on
    the way that is not coincident with the anchor (Spine1 -> Neck1 turns with Neck, Hand -> HandIndex1
    with FingerBase): that joint is the bone's rotation source. Leaf joints (and bones whose child is
    coincident) take their own anchor's rotation with their parent's bridge.
    """
    parents = clip.parents
    kids: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        kids.setdefault(int(p), []).append(j)
    mapped = set(bvh_of.values())
    anchor = np.empty(24, dtype=np.int64)
    for j, name in enumerate(JOINT_NAMES):
        b = bvh_of[name]
        if j > 0 and np.linalg.norm(rest[b] - rest[anchor[PARENTS[j]]]) <= tol:
            child = _BONE_CHILD.get(name)
            for k in _path(parents, kids, b, bvh_of[child] if child else None):
                if np.linalg.norm(rest[k] - rest[b]) > tol:
                    b = b if k in mapped else k
                    break
        anchor[j] = b
    source = anchor.copy()
    bridge = np.repeat(np.eye(3)[None], 24, axis=0)
    hips = rest[bvh_of["left_hip"]] - rest[bvh_of["right_hip"]]
    if np.linalg.norm(hips) <= tol:
        raise BvhError("LeftUpLeg and RightUpLeg coincide at rest")
    bridge[0] = _bridge(ours[JOINT_INDEX["left_hip"]] - ours[JOINT_INDEX["right_hip"]], hips)
    for j, name in enumerate(JOINT_NAMES[1:], start=1):
        child = _BONE_CHILD.get(name)
        a = int(anchor[j])
        first = None
        if child is not None:
            first = next((k for k in _path(parents, kids, a, int(anchor[JOINT_INDEX[child]]))
                          if np.linalg.norm(rest[k] - rest[a]) > tol), None)
        if child is None or first is None:
            bridge[j] = bridge[PARENTS[j]]
            continue
        source[j] = parents[first]
        bridge[j] = _bridge(ours[JOINT_INDEX[child]] - ours[j], rest[anchor[JOINT_INDEX[child]]] - rest[a])
    return JointMap(anchor, source, bridge)


def has_added_tpose(clip: BvhClip) -> bool:
    """Whether frame 0 is the T-pose the CMU BVH conversion (cgspeed, Hahne 2010) put before the take:
    every rotation channel a whole number of degrees (0, +-21, -16, 11, ...: not all zero, the legs and
    arms are set to reach CMU's T-pose), the root's rotation zero, and a jump of more than 10 degrees
    (at some joint) to frame 1. Clips re-exported since (6-decimal values) do not have it."""
    if clip.num_frames < 2:
        return False
    cols = [c for c, name in enumerate(ch for chans in clip.channels for ch in chans) if name[1:].lower() == "rotation"]
    root = [c for c, name in enumerate(clip.channels[0]) if name[1:].lower() == "rotation"]
    first = clip.values[0, cols]
    if not cols or np.any(clip.values[0, root] != 0) or np.any(first != np.round(first)):
        return False
    rot, _ = local_transforms(clip, slice(0, 2))
    rel = np.swapaxes(rot[0], -1, -2) @ rot[1]
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return bool(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() > 10.0)


DEFAULT_UP_REASON = "BVH default"  # detect_up's reason where the skeleton does not say


def detect_up(clip: BvhClip) -> tuple[str, str]:
    """("y" or "z", why): the axis the rest skeleton's Hips -> Head points along (CMU files are Y-up)."""
    names = {n: i for i, n in enumerate(clip.names)}
    if "Head" not in names:
        return "y", DEFAULT_UP_REASON
    d = rest_positions(clip)[names["Head"]]
    if d[2] > abs(d[1]) and d[2] > abs(d[0]):
        return "z", "the rest skeleton's Hips -> Head points along +Z"
    return "y", "the rest skeleton's Hips -> Head points along +Y" if d[1] > 0 else DEFAULT_UP_REASON


def _bridge(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    """rotation_between, also for opposite directions (a half turn about a perpendicular axis)."""
    a, b = ours / np.linalg.norm(ours), theirs / np.linalg.norm(theirs)
    if a @ b > -1.0 + 1e-9:
        return rotation_between(a, b)
    axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    return 2.0 * np.outer(axis, axis) - np.eye(3)


def retarget(clip: BvhClip, body: Body, name: str = "", source: str = "BVH", up: str = "y") -> Motion:
    """Retarget a parsed CMU-named BVH onto `body` (all frames, fps from the file); up="z": the file's world
    is Z-up and is turned Y-up first (a quarter turn about +X)."""
    col = _check_cmu(clip, source)
    pre = f"{source}: " if source else ""
    turn = Z_TO_Y if up == "z" else np.eye(3)
    rest = rest_positions(clip) @ turn.T
    bvh_of = {smpl: col[cmu] for cmu, smpl in CMU_TO_SMPL.items()}
    ours = body.joints.astype(np.float64)

    def length(a: str, b: str, pts: np.ndarray, index: dict[str, int]) -> float:
        return float(np.linalg.norm(pts[index[a]] - pts[index[b]]))

    leg_ours = length("left_knee", "left_hip", ours, JOINT_INDEX) + length("left_ankle", "left_knee", ours, JOINT_INDEX)
    leg_bvh = length("left_knee", "left_hip", rest, bvh_of) + length("left_ankle", "left_knee", rest, bvh_of)
    if not leg_bvh > 0:
        raise BvhError(f"{pre}the left leg (LeftUpLeg -> LeftLeg -> LeftFoot) has zero length")

    jmap = map_joints(clip, rest, ours, bvh_of, 1e-6 * leg_bvh)
    T = clip.num_frames
    poses = np.empty((T, 24, 3))
    root = np.empty((T, 3))
    for start in range(0, T, CHUNK_FRAMES):
        frames = slice(start, min(T, start + CHUNK_FRAMES))
        grot, gpos = global_fk(clip, frames)
        if up == "z":
            grot, gpos = turn @ grot @ turn.T, gpos @ turn.T
        g = grot[:, jmap.source] @ jmap.bridge[None]
        loc = g.copy()
        for j in range(1, 24):
            loc[:, j] = np.swapaxes(g[:, PARENTS[j]], -1, -2) @ g[:, j]
        poses[frames] = matrix_to_axis_angle(loc)
        root[frames] = gpos[:, col["Hips"]]
    scale = leg_ours / leg_bvh
    trans = root * scale - ours[0]  # pelvis world position = rest pelvis + trans
    if not (np.isfinite(poses).all() and np.isfinite(trans).all()):
        raise BvhError(f"{pre}retargeting gave NaN or inf")
    if np.abs(trans).max() > MAX_TRANSLATION_M:
        raise BvhError(f"{pre}the root (Hips) moves beyond {MAX_TRANSLATION_M:g} m (in metres, by the leg length)")
    return Motion(poses, trans, clip.fps, name)


def import_bvh(path: str | Path, body: Body, name: str | None = None) -> Motion:
    """Read a CMU-named, Y-up BVH file and retarget it onto `body` (every frame, fps from the file)."""
    return retarget(read_bvh(path), body, name or Path(path).stem, str(path))
