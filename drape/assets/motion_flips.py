"""Rotation flips in motion capture: a joint turns by a large angle in one frame and turns back soon after.

Real CMU files have them. In `05_10_dance.bvh` (120 fps) the right thigh's rotation jumps by about half a turn
between source frames 243 and 244 and jumps back between 252 and 253. The knee joint's position moves about 30 cm
in 1/120 s while the foot stays where it was: the capture solver swung the leg about the hip-ankle line for 9
frames. Of the 37 CMU clips in `../shared/data/mocap`, 16 hold jumps (turns over 1 rad in one 1/120 s frame,
up to 3.14 rad), 14 of them flips that turn back. The others turn at most 0.78 rad in a frame. A cloth simulator
driven by a flipped leg teleports the leg through the garment (`.venv/bin/python -m bench.motion_flips`;
docs/motion_import.md, docs/sim.md).

`find_flips` finds such jumps that turn back, per joint. `repair_flips` replaces the frames between a jump and its
return, for every joint at once, by slerp between the last frame before and the first frame after. Joints that
compensate for the flipped one (the ankle that kept the foot in place) are flipped too, and a span is short, so
all joints are interpolated. Root translation is kept: the capture's root marker does not flip. A jump that does
not turn back within `MAX_SPAN_S` is left alone: it may be a real, fast change.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from drape.assets.motion import Motion, _slerp
from drape.geometry.rotations import axis_angle_to_quaternion, quaternion_to_axis_angle
from drape.geometry.skeleton import JOINT_NAMES

# a jump is a frame-to-frame turn of at least FLIP_RAD radians that is also faster than FLIP_RAD_PER_S: at 120 fps
# the 21 CMU clips without jumps turn at most 0.78 rad a frame (94 rad/s), the jumps 1.06-3.14 rad; at 30 fps a fast,
# real turn of a rad a frame (30 rad/s) is not a jump
FLIP_RAD = 1.0
FLIP_RAD_PER_S = 60.0
# ... and it is a flip when a later jump, within MAX_SPAN_S, brings the joint back to less than RETURN_SHARE of the
# first jump's angle from the orientation it jumped from (the real motion goes on meanwhile: a dancer's hip turns
# 0.6-1.2 rad in the 0.1-0.2 s a flip lasts)
MAX_SPAN_S = 0.5
RETURN_SHARE = 0.75


@dataclass(frozen=True)
class Flip:
    """A span of frames [first, last] (inclusive, source frame indices) that a flip replaced, and the joints whose
    jumps marked it (indices into JOINT_NAMES) with the largest jump in radians."""

    first: int
    last: int
    joints: tuple[int, ...]
    jump_rad: float

    def describe(self) -> str:
        names = ", ".join(JOINT_NAMES[j] for j in self.joints)
        frames = f"frame {self.first}" if self.first == self.last else f"frames {self.first}-{self.last}"
        return f"{frames} ({names}; {self.jump_rad:.2f} rad)"


def _angles(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation from unit quaternions q0 to q1 (..., 4), sign-agnostic."""
    return 2.0 * np.arccos(np.abs(np.sum(q0 * q1, axis=-1)).clip(0.0, 1.0))


def _first_returns(q: np.ndarray, step: np.ndarray, ts: np.ndarray, max_span: int) -> np.ndarray:
    """For each jump ts[i] of one joint (q (T, 4) its quaternions, step (T - 1,) its turns, ts its jumps in
    frame order): the index i' > i of the first later jump within max_span frames that returns (the joint at
    ts[i'] + 1 less than RETURN_SHARE of the jump from where it jumped from), or -1.

    Vectorised over the jumps, one pass per offset i' - i while some jump has a later one within max_span
    (at most max_span passes): a file of a jump every frame that never returns costs T x max_span numbers,
    not T^2 / 2 Python steps (80,000 such frames took hours)."""
    n = len(ts)
    returns = np.full(n, -1, dtype=np.int64)
    for offset in range(1, n):
        i = np.flatnonzero((ts[offset:] - ts[:n - offset] <= max_span) & (returns[:n - offset] < 0))
        if not len(i):
            break  # the frames between jumps only grow with the offset: none is left to look for
        t, u = ts[i], ts[i + offset]
        back = _angles(q[t], q[u + 1]) < RETURN_SHARE * step[t]
        returns[i[back]] = i[back] + offset
    return returns


def find_flips(poses: np.ndarray, fps: float) -> list[Flip]:
    """poses: (T, J, 3) axis-angle, radians; fps: frames per second -> the flipped spans, merged over joints,
    in frame order. A span holds the frames after a jump up to and including the frame before its return.
    Jumps are paired greedily, each with the first later jump that returns."""
    q = axis_angle_to_quaternion(np.asarray(poses, dtype=np.float64))
    T = len(q)
    if T < 3:
        return []
    step = _angles(q[:-1], q[1:])  # (T - 1, J): turn from frame t to t + 1
    jump = (step >= FLIP_RAD) & (step * fps >= FLIP_RAD_PER_S)
    max_span = max(1, int(round(MAX_SPAN_S * fps)))
    spans: list[tuple[int, int, int, float]] = []  # first, last, joint, jump
    for joint in np.flatnonzero(jump.any(axis=0)):
        j = int(joint)
        ts = np.flatnonzero(jump[:, j])
        returns = _first_returns(q[:, j], step[:, j], ts, max_span)
        k = 0
        while k < len(ts):
            if returns[k] < 0:
                k += 1
                continue
            t, back = int(ts[k]), int(ts[returns[k]])
            spans.append((t + 1, back, j, float(step[t:back + 1, j].max())))
            k = int(returns[k]) + 1  # the jump after the return
    spans.sort()
    merged: list[Flip] = []
    for first, last, jt, a in spans:
        if merged and first <= merged[-1].last + 1:
            m = merged[-1]
            merged[-1] = Flip(m.first, max(m.last, last), tuple(sorted({*m.joints, jt})), max(m.jump_rad, a))
        else:
            merged.append(Flip(first, last, (jt,), a))
    return merged


def repair_flips(motion: Motion) -> tuple[Motion, list[Flip]]:
    """The motion with every flipped span's rotations (all joints) replaced by slerp between the frames around it,
    and the spans. A motion without flips comes back unchanged (the same object)."""
    flips = find_flips(motion.poses, motion.fps)
    if not flips:
        return motion, []
    q = axis_angle_to_quaternion(np.asarray(motion.poses, dtype=np.float64))
    for f in flips:
        a, b = f.first - 1, f.last + 1
        t = (np.arange(f.first, f.last + 1) - a) / (b - a)
        J = q.shape[1]
        q[f.first:f.last + 1] = _slerp(np.broadcast_to(q[a], (len(t), J, 4)), np.broadcast_to(q[b], (len(t), J, 4)),
                                       np.repeat(t[:, None], J, axis=1))
    poses = quaternion_to_axis_angle(q).astype(motion.poses.dtype)
    return replace(motion, poses=poses), flips
