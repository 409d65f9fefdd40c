"""Seeded procedural motions for training: gait cycles mixed with reaching and turning.

Each joint's local rotation is R = Rx(rx) @ Ry(ry) @ Rz(rz) from three channels,
every channel a sum of smooth terms (cubic-spline noise through random keys,
and the gait's periodic curves) clamped to a plausible range, so motions are C2
smooth (no pops) at any length. A gait amplitude in [0, 1] drifts between
standing and walking; the root turns at a smoothly varying rate and moves
forward with the gait; the pelvis height keeps the lower ankle at its rest
height. Conventions: drape's T-pose rest, +Y up, facing +Z, 30 fps by default.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from drape.assets.body import Body, load_body
from drape.assets.motion import Motion
from drape.geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from drape.geometry.skeleton import JOINT_INDEX, forward_kinematics

# (rx, ry, rz) ranges in radians, per joint (others stay at zero)
LIMITS: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "left_hip": ((-1.4, 0.5), (-0.4, 0.4), (-0.1, 0.5)),
    "right_hip": ((-1.4, 0.5), (-0.4, 0.4), (-0.5, 0.1)),
    "left_knee": ((0.0, 2.0), (0.0, 0.0), (0.0, 0.0)),
    "right_knee": ((0.0, 2.0), (0.0, 0.0), (0.0, 0.0)),
    "left_ankle": ((-0.4, 0.5), (-0.2, 0.2), (-0.2, 0.2)),
    "right_ankle": ((-0.4, 0.5), (-0.2, 0.2), (-0.2, 0.2)),
    "spine1": ((-0.25, 0.4), (-0.3, 0.3), (-0.2, 0.2)),
    "spine2": ((-0.2, 0.3), (-0.3, 0.3), (-0.15, 0.15)),
    "spine3": ((-0.2, 0.3), (-0.3, 0.3), (-0.15, 0.15)),
    "neck": ((-0.4, 0.5), (-0.6, 0.6), (-0.3, 0.3)),
    "left_shoulder": ((-1.8, 0.7), (-0.5, 0.5), (-1.45, 0.6)),
    "right_shoulder": ((-1.8, 0.7), (-0.5, 0.5), (-0.6, 1.45)),
    "left_elbow": ((0.0, 0.0), (-2.2, 0.0), (0.0, 0.0)),
    "right_elbow": ((0.0, 0.0), (0.0, 2.2), (0.0, 0.0)),
}


# real CMU mocap imported onto drape's skeleton (drape.assets.bvh) carries rotations at the upper back and the
# clavicles that the channels below never make: over DeePSD's 31 real training clips (its manifest's mocap.train,
# at 30 fps) the local axis-angle of spine3 averages (-0.49, -0.05, 0.01) rad (std 0.15, 0.13, 0.11 per axis), the
# left collar's (0.32, -0.02, 0.43) (std 0.12, 0.16, 0.16) and the right's (0.30, 0.09, -0.41) (0.14, 0.13, 0.17)
# (a one-off measurement, logs/ not kept; the validation and evaluation clips were not read for it)
POSTURE: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {  # joint: (mean, std) rad
    "spine3": ((-0.49, -0.05, 0.01), (0.15, 0.13, 0.11)),
    "left_collar": ((0.32, -0.02, 0.43), (0.12, 0.16, 0.16)),
    "right_collar": ((0.30, 0.09, -0.41), (0.14, 0.13, 0.17)),
}
POSTURE_DRIFT = 0.05  # rad: smooth drift of each posture channel around the motion's draw


def smooth_noise(n: int, fps: float, rng: np.random.Generator, period: float, scale: float = 1.0) -> np.ndarray:
    """(n,) C2-smooth random signal: a cubic spline through N(0, scale^2) keys every ~`period` s."""
    duration = max(n / fps, 1e-3)
    keys = max(4, int(np.ceil(duration / period)) + 3)
    kt = np.linspace(-period, duration + period, keys)
    return CubicSpline(kt, rng.normal(0.0, scale, keys))(np.arange(n) / fps)


def _rot(rx: np.ndarray, ry: np.ndarray, rz: np.ndarray) -> np.ndarray:
    z = np.zeros_like(rx)
    return (
        axis_angle_to_matrix(np.stack([rx, z, z], -1))
        @ axis_angle_to_matrix(np.stack([z, ry, z], -1))
        @ axis_angle_to_matrix(np.stack([z, z, rz], -1))
    )


def _add_posture(local: np.ndarray, fps: float, rng: np.random.Generator, amount: float) -> None:
    """Rotate spine3 and the collars of local rotations (T, 24, 3, 3) in place by a captured skeleton's posture
    (`POSTURE`: one draw per motion, amount x (mean + std x N(0, 1)), plus a smooth drift). Their children's local
    rotations stay as they are, as in the real clips (whose neck and shoulders average what the channels here
    make: e.g. the left shoulder (0.20, -0.41, -1.41) rad against (-0.14, -0.11, -1.36)), so the head and the arms
    turn with the chest and the clavicles."""
    n = len(local)
    for name, (mean, std) in POSTURE.items():
        draw = np.asarray(mean) + np.asarray(std) * rng.normal(size=3)
        drift = np.stack([POSTURE_DRIFT * smooth_noise(n, fps, rng, 1.8) for _ in range(3)], -1)
        local[:, JOINT_INDEX[name]] = local[:, JOINT_INDEX[name]] @ axis_angle_to_matrix(amount * (draw[None] + drift))


def _spread_legs(ch: dict[str, list[np.ndarray]], n: int, fps: float, rng: np.random.Generator,
                 spread: float) -> None:
    """Add legs-apart bursts to the (rx, ry, rz) channels `ch` in place: one signal's positive lobes lift
    the left leg, its negative lobes the right one (never both), the other leg reaching back."""
    side_signal = smooth_noise(n, fps, rng, 1.3)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        lift = spread * 1.5 * np.clip(sign * side_signal - 0.5, 0.0, 1.0)  # bursts where |signal| > 0.5
        back = spread * 1.5 * np.clip(-sign * side_signal - 0.5, 0.0, 1.0)
        ch[f"{side}_hip"][0] += -1.0 * lift + 0.35 * back  # swing forward, or reach back
        ch[f"{side}_hip"][2] += sign * 0.35 * lift * np.abs(smooth_noise(n, fps, rng, 1.0))  # and out
        ch[f"{side}_knee"][0] += 0.4 * back  # the standing leg bends a little


def generate_motion(
    frames: int,
    seed: int = 0,
    fps: float = 30.0,
    body: str | Body = "neutral",
    walk: float = 0.6,
    spread: float = 0.0,
    posture: float = 0.0,
) -> Motion:
    """A procedural motion of `frames` frames.

    walk: share of the time spent walking rather than standing, reaching and turning (0..1).
    spread: amplitude (0..1) of legs-apart bursts: one leg at a time swung forward and out (a kick, a lunge,
        a wide step) while the other reaches back, up to the hips' limits (at 1 the ankles reach 1.45-1.49 m
        apart, like the DeepMimic kick's 1.43 m). Drawn from a second generator, so `spread=0` gives exactly the motion without it.
    posture: amplitude (0..1) of a captured skeleton's upper-back and clavicle rotations (`_add_posture`), which
        the channels above keep at zero. Drawn from a third generator, so `posture=0` gives exactly the motion
        without it.
    """
    if frames < 1:
        raise ValueError("frames must be >= 1")
    for name, share in (("walk", walk), ("spread", spread), ("posture", posture)):
        if not 0.0 <= share <= 1.0:  # NaN too
            raise ValueError(f"{name} must be within [0, 1], got {share}")
    b = load_body(body) if isinstance(body, str) else body
    rng = np.random.default_rng(seed)
    n = frames
    ch: dict[str, list[np.ndarray]] = {j: [np.zeros(n), np.zeros(n), np.zeros(n)] for j in LIMITS}

    # gait: amplitude drifts between standing (0) and walking (1)
    g = 1.0 / (1.0 + np.exp(-3.0 * (smooth_noise(n, fps, rng, 2.5) + 2.0 * (walk - 0.5))))
    cadence = 0.9 + 0.15 * smooth_noise(n, fps, rng, 3.0)  # strides per second
    phase = 2 * np.pi * np.cumsum(cadence) / fps + rng.uniform(0, 2 * np.pi)
    for side, shift in (("left", 0.0), ("right", np.pi)):
        p = phase + shift
        ch[f"{side}_hip"][0] += -g * (0.1 + 0.42 * np.sin(p))
        ch[f"{side}_knee"][0] += g * (0.12 + 0.95 * (0.5 + 0.5 * np.sin(p + 1.6)) ** 3)
        ch[f"{side}_ankle"][0] += g * 0.2 * np.sin(p - 0.4)
        ch[f"{side}_shoulder"][0] += g * 0.4 * np.sin(p)  # arms swing against the same-side leg
        down = 1.25 + 0.1 * smooth_noise(n, fps, rng, 2.0)
        ch[f"{side}_shoulder"][2] += -down if side == "left" else down
    # reaching and idle motion, larger when standing
    idle = 1.0 - 0.7 * g
    for side, sign in (("left", -1.0), ("right", 1.0)):
        sh = ch[f"{side}_shoulder"]
        sh[0] += idle * (0.7 * smooth_noise(n, fps, rng, 1.2) - 0.3)
        sh[1] += idle * 0.25 * smooth_noise(n, fps, rng, 1.5)
        sh[2] += sign * idle * 0.6 * np.abs(smooth_noise(n, fps, rng, 1.4))
        ch[f"{side}_elbow"][1] += sign * (0.25 + idle * 0.9 * np.abs(smooth_noise(n, fps, rng, 1.0)))
        ch[f"{side}_hip"][1] += 0.1 * smooth_noise(n, fps, rng, 2.0)
        ch[f"{side}_hip"][2] += sign * -0.06 * np.abs(smooth_noise(n, fps, rng, 2.0))
        ch[f"{side}_knee"][0] += idle * 0.15 * np.abs(smooth_noise(n, fps, rng, 2.0))
    for name, amp in (("spine1", 0.12), ("spine2", 0.1), ("spine3", 0.1), ("neck", 0.25)):
        for axis in range(3):
            ch[name][axis] += amp * smooth_noise(n, fps, rng, 1.8)
    ch["spine1"][0] += 0.05 * g  # lean into the walk
    if spread > 0:
        _spread_legs(ch, n, fps, np.random.default_rng([seed, 1]), spread)

    local = np.repeat(np.eye(3)[None, None], 24, axis=1).repeat(n, axis=0)
    for name, (lx, ly, lz) in LIMITS.items():
        rx, ry, rz = (np.clip(c, lo, hi) for c, (lo, hi) in zip(ch[name], (lx, ly, lz), strict=True))
        local[:, JOINT_INDEX[name]] = _rot(rx, ry, rz)
    if posture > 0:
        _add_posture(local, fps, np.random.default_rng([seed, 2]), posture)
    # root: smoothly varying turn rate, forward speed from the gait
    yaw = rng.uniform(-np.pi, np.pi) + np.cumsum(0.6 * smooth_noise(n, fps, rng, 2.0)) / fps
    local[:, 0] = _rot(np.zeros(n), yaw, np.zeros(n))
    poses = matrix_to_axis_angle(local)
    speed = g * cadence * 1.3  # metres per second, ~1.3 m per stride
    step = speed / fps
    trans = np.zeros((n, 3))
    trans[:, 0] = np.cumsum(step * np.sin(yaw))
    trans[:, 2] = np.cumsum(step * np.cos(yaw))
    # keep the lower ankle at its rest height
    _, joints = forward_kinematics(poses, b.joints)
    ankles = joints[:, [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]], 1].min(axis=1)
    trans[:, 1] = b.joints[JOINT_INDEX["left_ankle"], 1] - ankles
    return Motion(poses, trans, fps, f"procedural_{seed}")
