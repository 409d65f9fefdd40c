"""One garment on one body driven by one motion, simulated with MuJoCo 4 flex cloth.

The cloth is a `flexcomp type="direct" dim="2"` shell built from the garment's
triangles (one body with three slide DOFs per vertex), with the intrinsic
parameters of `SimParams`. The body collider is `collider.fit_hulls`: convex
slabs carried by one body per bone, moved every substep to the bone's skinning
transform (positions interpolated linearly, rotations by normalised quaternion
lerp between frames). The bone bodies are kinematic: heavy free bodies whose
position *and velocity* are written every substep, so contacts know how fast
the leg moves. (Mocap bodies teleport with no velocity: a walking leg then
passed through the cloth, centimetres deep, in development.)

Sequence: a settle phase blends the pose (and translation) from the rest pose
to the first motion frame over `settle_blend` frames and holds it for
`settle_hold` frames, so the garment drapes from its rest shape; then the
motion runs at its fps with `substeps` steps per frame. Only motion frames are
returned.

Waistband: the vertices of the garment's highest boundary loop (within 2 cm of
its top) are pinned to the body, i.e. moved kinematically by linear blend
skinning with the nearest body vertex's weights, as an elastic waistband or a
neckline on the shoulders would hold them. `pin_top=False` turns it off.

Air drag: MuJoCo has no drag on flex vertices, so a force -c * area_i * v_i is
applied to every vertex each step (area_i: a third of its triangles' rest area).
The cloth does not collide with itself (not modelled).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drape.assets.body import Body
from drape.assets.motion import Motion
from drape.geometry.lbs import linear_blend_skinning
from drape.geometry.mesh import boundary_edges
from drape.geometry.queries import nearest_vertex_weights
from drape.geometry.rotations import (
    matrix_to_quaternion,
    quaternion_multiply,
    quaternion_to_axis_angle,
)
from drape.geometry.skeleton import forward_kinematics
from drape.sim.collider import Hull, fit_hulls, garment_bones
from drape.sim.params import SimParams
from drape.sim.quality import sequence_stats


@dataclass
class SimResult:
    """vertices (T, N, 3) float32 m; poses (T, 24, 3) float32 rad; trans (T, 3) float32 m;
    stats: quality statistics (see quality.sequence_stats); seconds: wall time of the simulation."""

    vertices: np.ndarray
    poses: np.ndarray
    trans: np.ndarray
    params: SimParams
    stats: dict
    seconds: float
    settle_frames: int

    @property
    def seconds_per_frame(self) -> float:
        return self.seconds / (len(self.vertices) + self.settle_frames)


def _fmt(a: np.ndarray) -> str:
    return " ".join(f"{x:.6g}" for x in np.asarray(a, dtype=np.float64).ravel())


def vertex_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N,) m^2: a third of the area of each vertex's triangles."""
    tri = vertices[faces].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    out = np.zeros(len(vertices))
    np.add.at(out, faces.ravel(), np.repeat(area / 3.0, 3))
    return out


def top_boundary(vertices: np.ndarray, faces: np.ndarray, band: float = 0.02) -> np.ndarray:
    """Indices of boundary vertices within `band` metres (in Y) of the highest boundary vertex."""
    b = np.unique(boundary_edges(faces))
    if len(b) == 0:
        return b.astype(np.int64)
    return b[vertices[b, 1] >= vertices[b, 1].max() - band].astype(np.int64)


def scene_xml(vertices: np.ndarray, faces: np.ndarray, hulls: list[Hull], params: SimParams, fps: float) -> str:
    """MJCF of the cloth (in rest pose) and one kinematic body per bone carrying its hulls."""
    area = float(vertex_areas(vertices, faces).sum())
    assets = "".join(f'<mesh name="h{i}" vertex="{_fmt(h.vertices)}"/>' for i, h in enumerate(hulls))
    bones = sorted({h.bone for h in hulls})
    bodies = "".join(
        f'<body name="bone{k}" gravcomp="1"><freejoint/><inertial pos="0 0 0" mass="1000" diaginertia="100 100 100"/>'
        + "".join(f'<geom type="mesh" mesh="h{i}" contype="1" conaffinity="0" rgba=".8 .7 .6 1"/>'
                  for i, h in enumerate(hulls) if h.bone == k)
        + "</body>"
        for k in bones
    )
    p = params
    return f"""<mujoco model="drape-cloth">
  <compiler autolimits="true"/>
  <option timestep="{1.0 / (fps * p.substeps):.8g}" integrator="discrete" solver="CG"
          iterations="{p.iterations}" gravity="0 {-p.gravity:.8g} 0"/>
  <asset>{assets}</asset>
  <worldbody>{bodies}
    <flexcomp name="cloth" type="direct" dim="2" dof="full" radius="0.001" mass="{p.density * area:.8g}"
              point="{_fmt(vertices)}" element="{' '.join(map(str, np.asarray(faces).ravel()))}">
      <elasticity young="{p.young:.8g}" poisson="{p.poisson:.8g}" thickness="{p.thickness:.8g}"
                  damping="{p.damping:.8g}" elastic2d="both"/>
      <contact contype="0" conaffinity="1" condim="3" solref="{p.contact_timeconst:.8g} 1" solimp="0.95 0.99 0.001"
               margin="{p.contact_margin:.8g}" friction="{p.friction:.8g}" selfcollide="none"/>
    </flexcomp>
  </worldbody>
</mujoco>"""


def _bone_frames(body: Body, poses: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Skinning transforms (T, 24, 4, 4) plus their translations (T, 24, 3) and quaternions (T, 24, 4)."""
    tr, _ = forward_kinematics(poses, body.joints, body.parents, trans)
    q = matrix_to_quaternion(tr[..., :3, :3])
    # keep consecutive quaternions in the same hemisphere so lerping between frames is short
    for t in range(1, len(q)):
        flip = np.einsum("kc,kc->k", q[t], q[t - 1]) < 0
        q[t, flip] *= -1
    return tr, tr[..., :3, 3], q


def settle_motion(motion: Motion, frames: int, blend: int, hold: int) -> tuple[np.ndarray, np.ndarray]:
    """Settle frames then the first `frames` motion frames: poses (S + T, 24, 3), trans (S + T, 3).

    The settle frames go from the rest pose (zero rotations, the first frame's
    translation with its height taken from the rest pose, i.e. 0) to the first
    frame linearly in axis-angle over `blend` frames, then hold it `hold` frames.
    """
    poses = motion.poses[:frames].astype(np.float64)
    trans = motion.trans[:frames].astype(np.float64)
    w = np.minimum(np.arange(1, blend + 1) / blend, 1.0) if blend else np.zeros(0)
    w = np.concatenate([[0.0], w, np.ones(hold)])
    pre_p = poses[0][None] * w[:, None, None]
    t0 = trans[0].copy()
    pre_t = np.stack([np.array([t0[0], t0[1] * wi, t0[2]]) for wi in w]) if len(w) else np.zeros((0, 3))
    return np.concatenate([pre_p, poses]), np.concatenate([pre_t, trans])


def simulate(
    garment_vertices: np.ndarray,
    faces: np.ndarray,
    body: Body,
    motion: Motion,
    params: SimParams | None = None,
    frames: int | None = None,
    settle_blend: int = 15,
    settle_hold: int = 15,
    pin_top: bool = True,
    hulls: list[Hull] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SimResult:
    """Simulate a garment (rest pose on `body`) along `motion`.

    garment_vertices: (N, 3) metres, rest pose of `body`; faces: (F, 3) int;
    frames: how many motion frames (all when None; the motion must have that many).
    Returns a SimResult with vertices (frames, N, 3) float32 and quality stats.
    `progress(done, total)` is called after every frame, settle frames included.
    """
    import mujoco

    params = params or SimParams()
    V0 = np.asarray(garment_vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    T = motion.num_frames if frames is None else int(frames)
    if not 1 <= T <= motion.num_frames:
        raise ValueError(f"frames must be in [1, {motion.num_frames}] for clip {motion.name!r}, got {T}")
    if hulls is None:
        hulls = fit_hulls(body, garment_bones(body, V0.astype(np.float32), reach=0.2))
    all_p, all_t = settle_motion(motion, T, settle_blend, settle_hold)
    S = len(all_p) - T
    tr, pos, quat = _bone_frames(body, all_p, all_t)

    t_start = time.perf_counter()
    # the cloth starts in rest pose under the body's first horizontal position (the settle frames' translation)
    start = V0 + all_t[0]
    model = mujoco.MjModel.from_xml_string(scene_xml(start, F, hulls, params, motion.fps))
    data = mujoco.MjData(model)
    bones = sorted({h.bone for h in hulls})
    bone_body = np.array([model.body(f"bone{k}").id for k in bones])
    bone_q = (model.jnt_qposadr[model.body_jntadr[bone_body]][:, None] + np.arange(7)).ravel()
    bone_d = (model.jnt_dofadr[model.body_jntadr[bone_body]][:, None] + np.arange(6)).ravel()
    # body-frame angular velocity from frame f - 1 to f: q_f = q_{f-1} * exp(w dt)
    rel = quaternion_multiply(quat[:-1] * np.array([1, -1, -1, -1]), quat[1:])
    omega = quaternion_to_axis_angle(rel) * motion.fps  # (S + T - 1, 24, 3)
    vel = np.diff(pos, axis=0) * motion.fps
    vbody = np.array([model.body(f"cloth_{i}").id for i in range(len(V0))])
    dof = model.jnt_dofadr[model.body_jntadr[vbody]]  # 3 slide DOFs (x, y, z) per vertex, consecutive
    qadr = model.jnt_qposadr[model.body_jntadr[vbody]]
    dof3 = (dof[:, None] + np.arange(3)).ravel()
    drag = np.repeat(params.air_drag * vertex_areas(V0, F), 3)

    pinned = top_boundary(V0, F) if pin_top else np.zeros(0, dtype=np.int64)
    if len(pinned):
        pin_w = nearest_vertex_weights(V0[pinned], body.vertices, body.weights)
        pin_xyz = linear_blend_skinning(V0[pinned], pin_w, tr).astype(np.float64)  # (S + T, P, 3)
        pin_q = (qadr[pinned][:, None] + np.arange(3)).ravel()
        pin_d = (dof[pinned][:, None] + np.arange(3)).ravel()
        pin_rest = start[pinned].ravel()
        # kinematic pins: positions and velocities are written every substep, but within a step the
        # solver still moves them under the garment's weight; a heavy vertex barely moves (a light one
        # sags by ~ tension / mass * dt^2, centimetres, stretching the first row of edges)
        model.body_mass[vbody[pinned]] *= 1e4
        mujoco.mj_setConst(model, data)

    def place(f: int, a: float) -> None:
        """Move bones (and pinned vertices) to fraction a of the way from frame f - 1 to f."""
        q = (1 - a) * quat[f - 1, bones] + a * quat[f, bones]
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        x = (1 - a) * pos[f - 1, bones] + a * pos[f, bones]
        data.qpos[bone_q] = np.concatenate([x, q], axis=1).ravel()
        data.qvel[bone_d] = np.concatenate([vel[f - 1, bones], omega[f - 1, bones]], axis=1).ravel()
        if len(pinned):
            x = (1 - a) * pin_xyz[f - 1] + a * pin_xyz[f]
            data.qpos[pin_q] = x.ravel() - pin_rest
            data.qvel[pin_d] = ((pin_xyz[f] - pin_xyz[f - 1]) * motion.fps).ravel()

    data.qpos[bone_q] = np.concatenate([pos[0, bones], quat[0, bones]], axis=1).ravel()
    mujoco.mj_forward(model, data)
    out = np.empty((T, len(V0), 3), dtype=np.float32)
    total = len(all_p) - 1
    for f in range(1, len(all_p)):
        for s in range(params.substeps):
            place(f, (s + 1) / params.substeps)
            data.qfrc_applied[dof3] = -drag * data.qvel[dof3]
            mujoco.mj_step(model, data)
        if f >= S:
            out[f - S] = data.flexvert_xpos
        if progress is not None:
            progress(f, total)
    seconds = time.perf_counter() - t_start
    poses = motion.poses[:T].astype(np.float32)
    trans = motion.trans[:T].astype(np.float32)
    stats = sequence_stats(out, V0.astype(np.float32), F, body, poses, trans)
    stats["seconds"] = round(seconds, 3)
    stats["seconds_per_frame"] = round(seconds / (T + S), 4)
    return SimResult(out, poses, trans, params, stats, seconds, S)
