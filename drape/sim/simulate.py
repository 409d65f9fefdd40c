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
from drape.geometry.mesh import boundary_edges
from drape.geometry.queries import nearest_vertex_weights
from drape.geometry.rotations import (
    matrix_to_quaternion,
    quaternion_multiply,
    quaternion_to_axis_angle,
)
from drape.geometry.skeleton import forward_kinematics
from drape.sim.collider import Hull, fit_hulls, garment_bones
from drape.sim.params import CLOTH_RADIUS, SimParams
from drape.sim.quality import sequence_stats

PIN_MASS_SCALE = 1e4  # a pinned vertex's mass, times its share of the cloth's (see simulate_cloths)


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


@dataclass(frozen=True)
class Cloth:
    """One flex in the scene: rest-pose vertices (N, 3) m on the body, faces (F, 3), and how it collides.

    radius: the flex elements' collision radius (m); margin: its contact margin (None: the parameter set's
    `contact_margin`). MuJoCo 4 adds the margins of the two sides of a contact and measures the distance
    between the radius-thickened surfaces, so two cloths' mid-surfaces rest about r1 + r2 + m1 + m2 apart
    and a cloth's mid-surface rests r + m off the body. contype / conaffinity: MuJoCo's collision bitmasks
    (the body hulls are contype 1, conaffinity 0).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    radius: float = CLOTH_RADIUS
    margin: float | None = None
    contype: int = 0
    conaffinity: int = 1


def _flex_xml(c: Cloth, start: np.ndarray, p: SimParams) -> str:
    margin = p.contact_margin if c.margin is None else c.margin
    area = float(vertex_areas(start, c.faces).sum())
    return f"""
    <flexcomp name="{c.name}" type="direct" dim="2" dof="full" radius="{c.radius:.8g}" mass="{p.density * area:.8g}"
              point="{_fmt(start)}" element="{' '.join(map(str, np.asarray(c.faces).ravel()))}">
      <elasticity young="{p.young:.8g}" poisson="{p.poisson:.8g}" thickness="{p.thickness:.8g}"
                  damping="{p.damping:.8g}" elastic2d="both"/>
      <contact contype="{c.contype}" conaffinity="{c.conaffinity}" condim="3" solref="{p.contact_timeconst:.8g} 1"
               solimp="0.95 0.99 0.001" margin="{margin:.8g}" friction="{p.friction:.8g}" selfcollide="none"/>
    </flexcomp>"""


def scene_xml(cloths: list[tuple[Cloth, np.ndarray]], hulls: list[Hull], params: SimParams, fps: float) -> str:
    """MJCF of the cloths (each with its start positions (N, 3)) and one kinematic body per bone carrying its hulls."""
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
    flexes = "".join(_flex_xml(c, start, p) for c, start in cloths)
    return f"""<mujoco model="drape-cloth">
  <compiler autolimits="true"/>
  <option timestep="{1.0 / (fps * p.substeps):.8g}" integrator="discrete" solver="CG"
          iterations="{p.iterations}" gravity="0 {-p.gravity:.8g} 0"/>
  <asset>{assets}</asset>
  <worldbody>{bodies}{flexes}
  </worldbody>
</mujoco>"""


def compile_scene(cloths: list[Cloth], starts: list[np.ndarray], pinned: list[np.ndarray], hulls: list[Hull],
                  params: SimParams, fps: float):
    """The scene's mujoco.MjModel: `scene_xml` of the cloths (each at its start positions (N, 3) m) and hulls, each
    cloth's pinned vertices (indices (P,)) PIN_MASS_SCALE times heavier.

    Kinematic pins: positions and velocities are written every substep, but within a step the solver still moves
    them under the garment's weight; a heavy vertex barely moves (a light one sags by ~ tension / mass * dt^2,
    centimetres, stretching the first row of edges). The masses are set in the spec before it compiles, so the
    compiler derives every constant from them. (Setting model.body_mass after compiling needs mj_setConst, which
    recomputes the flexes' bending coefficients as well: ~35 s for a 3k-vertex cloth, as long as the compile
    itself, for the same model to the bit; bench.sim_setup.)"""
    import mujoco

    spec = mujoco.MjSpec.from_string(scene_xml(list(zip(cloths, starts, strict=True)), hulls, params, fps))
    for c, index in zip(cloths, pinned, strict=True):
        for i in index:
            spec.body(f"{c.name}_{i}").mass *= PIN_MASS_SCALE
    return spec.compile()


def float32_grid(x: np.ndarray) -> np.ndarray:
    """x (any shape) rounded to the nearest float32 and returned as float64.

    The simulation's kinematic inputs go through this so that the last bits of numpy's SIMD paths do not reach
    MuJoCo: numpy picks its transcendental and reduction loops by CPU (AVX512 or AVX2), which differ by an ulp or
    two (measured: the bones' angular velocities by 1.8e-15 rad/s on dance_b), and the contact dynamics amplify that
    (the tank top + long sleeve's outer cloth on dance_b 6.2 mm RMS apart after 60 frames). A float32 grid is
    1e-7 relative: far below anything the cloth responds to, far above those differences."""
    return np.asarray(x, dtype=np.float64).astype(np.float32).astype(np.float64)


def pin_targets(rest: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Where the pinned vertices go: rest (P, 3) m, weights (P, K) rows summing to 1, transforms (F, K, 4, 4) ->
    (F, P, 3) m on the float32 grid (`float32_grid`).

    Linear blend skinning as `drape.geometry.lbs.linear_blend_skinning`, but in float64 by elementwise products and
    sums in a fixed order (over joints, then over the rest coordinates): no BLAS call, whose kernels OpenBLAS picks
    by CPU (AVX2 or AVX512, which round a float32 GEMM differently: measured, the held-out jacket's simulated H-Coll
    on dance_b 3.56% under one kernel and 4.40% under the other). Elementwise IEEE products and sums round the same
    at every SIMD width, so the targets are the same bytes on every CPU."""
    w = np.asarray(weights, dtype=np.float64)
    tr = np.asarray(transforms, dtype=np.float64)[:, :, :3, :]  # (F, K, 3, 4)
    blended = np.zeros((len(tr), len(w), 3, 4))
    for k in np.flatnonzero(np.any(w != 0, axis=0)):
        blended += w[None, :, k, None, None] * tr[:, None, k]
    v = np.asarray(rest, dtype=np.float64)
    out = blended[..., 3].copy()
    for j in range(3):
        out += blended[..., j] * v[None, :, j, None]
    return float32_grid(out)


def bone_kinematics(body: Body, poses: np.ndarray, trans: np.ndarray, fps: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What moves the bone hulls, for poses (F, 24, 3) rad and trans (F, 3) m at fps: skinning transforms
    (F, 24, 4, 4); bone positions (F, 24, 3) m and quaternions (F, 24, 4) (w, x, y, z; consecutive ones in the
    same hemisphere, so lerping between frames is short); from each frame to the next the body-frame angular
    velocity (F - 1, 24, 3) rad/s (q_f = q_{f-1} exp(w dt)) and the linear velocity (F - 1, 24, 3) m/s. All but
    the transforms on the float32 grid (`float32_grid`), so they are the same bytes on every CPU."""
    tr, _ = forward_kinematics(poses, body.joints, body.parents, trans)
    q = matrix_to_quaternion(tr[..., :3, :3])
    for t in range(1, len(q)):
        flip = np.einsum("kc,kc->k", q[t], q[t - 1]) < 0
        q[t, flip] *= -1
    pos = tr[..., :3, 3]
    rel = quaternion_multiply(q[:-1] * np.array([1, -1, -1, -1]), q[1:])
    omega = quaternion_to_axis_angle(rel) * fps
    vel = np.diff(pos, axis=0) * fps
    return tr, float32_grid(pos), float32_grid(q), float32_grid(omega), float32_grid(vel)


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


@dataclass
class ClothRun:
    """What `simulate_cloths` returns: vertices per cloth (T, N_c, 3) float32, the motion frames' poses
    (T, 24, 3) and trans (T, 3) float32, wall time and the number of settle frames before them."""

    vertices: list[np.ndarray]
    poses: np.ndarray
    trans: np.ndarray
    seconds: float
    settle_frames: int


def simulate_cloths(
    cloths: list[Cloth],
    body: Body,
    motion: Motion,
    params: SimParams,
    frames: int | None = None,
    settle_blend: int = 15,
    settle_hold: int = 15,
    pin_top: bool = True,
    hulls: list[Hull] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ClothRun:
    """Simulate one or more cloths (each in rest pose on `body`) together along `motion`.

    The shared engine of `simulate` (one garment) and `drape.sim.layers.simulate_layers` (two): each
    cloth is its own flex, with its own pinned top boundary, air drag and collision settings.
    """
    import mujoco

    T = motion.num_frames if frames is None else int(frames)
    if not 1 <= T <= motion.num_frames:
        raise ValueError(f"frames must be in [1, {motion.num_frames}] for clip {motion.name!r}, got {T}")
    rest = [np.asarray(c.vertices, dtype=np.float64) for c in cloths]
    if hulls is None:
        hulls = fit_hulls(body, garment_bones(body, np.concatenate(rest).astype(np.float32), reach=0.2))
    if not hulls:  # no bone within reach: the scene would have no body (an IndexError further down)
        raise ValueError("no part of the body lies within 0.2 m of the garment at rest: a garment to simulate must "
                         "be in the body's rest pose, on the body (drape outfits fit puts one there)")
    all_p, all_t = settle_motion(motion, T, settle_blend, settle_hold)
    S = len(all_p) - T
    tr, pos, quat, omega, vel = bone_kinematics(body, all_p, all_t, motion.fps)

    t_start = time.perf_counter()
    # the cloth starts in rest pose under the body's first horizontal position (the settle frames' translation)
    starts = [V0 + all_t[0] for V0 in rest]
    pinned_of = [top_boundary(V0, c.faces) if pin_top else np.zeros(0, dtype=np.int64)
                 for c, V0 in zip(cloths, rest, strict=True)]
    model = compile_scene(cloths, starts, pinned_of, hulls, params, motion.fps)
    data = mujoco.MjData(model)
    bones = sorted({h.bone for h in hulls})
    bone_body = np.array([model.body(f"bone{k}").id for k in bones])
    bone_q = (model.jnt_qposadr[model.body_jntadr[bone_body]][:, None] + np.arange(7)).ravel()
    bone_d = (model.jnt_dofadr[model.body_jntadr[bone_body]][:, None] + np.arange(6)).ravel()

    dof3_all, drag_all = [], []
    pin_q_all, pin_d_all, pin_rest_all, pin_xyz_all = [], [], [], []
    for c, V0, start, pinned in zip(cloths, rest, starts, pinned_of, strict=True):
        vbody = np.array([model.body(f"{c.name}_{i}").id for i in range(len(V0))])
        dof = model.jnt_dofadr[model.body_jntadr[vbody]]  # 3 slide DOFs (x, y, z) per vertex, consecutive
        qadr = model.jnt_qposadr[model.body_jntadr[vbody]]
        dof3_all.append((dof[:, None] + np.arange(3)).ravel())
        drag_all.append(float32_grid(np.repeat(params.air_drag * vertex_areas(V0, c.faces), 3)))
        if len(pinned):
            pin_w = nearest_vertex_weights(V0[pinned], body.vertices, body.weights)
            pin_xyz_all.append(pin_targets(V0[pinned], pin_w, tr))  # (S + T, P, 3)
            pin_q_all.append((qadr[pinned][:, None] + np.arange(3)).ravel())
            pin_d_all.append((dof[pinned][:, None] + np.arange(3)).ravel())
            pin_rest_all.append(start[pinned].ravel())
    dof3, drag = np.concatenate(dof3_all), np.concatenate(drag_all)
    pinning = bool(pin_q_all)
    if pinning:
        pin_xyz = np.concatenate(pin_xyz_all, axis=1)
        pin_q, pin_d, pin_rest = np.concatenate(pin_q_all), np.concatenate(pin_d_all), np.concatenate(pin_rest_all)

    def place(f: int, a: float) -> None:
        """Move bones (and pinned vertices) to fraction a of the way from frame f - 1 to f."""
        q = (1 - a) * quat[f - 1, bones] + a * quat[f, bones]
        q /= np.sqrt(q[:, :1] ** 2 + q[:, 1:2] ** 2 + q[:, 2:3] ** 2 + q[:, 3:] ** 2)  # elementwise: no SIMD-width sum
        x = (1 - a) * pos[f - 1, bones] + a * pos[f, bones]
        data.qpos[bone_q] = np.concatenate([x, q], axis=1).ravel()
        data.qvel[bone_d] = np.concatenate([vel[f - 1, bones], omega[f - 1, bones]], axis=1).ravel()
        if pinning:
            x = (1 - a) * pin_xyz[f - 1] + a * pin_xyz[f]
            data.qpos[pin_q] = x.ravel() - pin_rest
            data.qvel[pin_d] = ((pin_xyz[f] - pin_xyz[f - 1]) * motion.fps).ravel()

    data.qpos[bone_q] = np.concatenate([pos[0, bones], quat[0, bones]], axis=1).ravel()
    mujoco.mj_forward(model, data)
    adr = model.flex_vertadr
    outs = [np.empty((T, len(V0), 3), dtype=np.float32) for V0 in rest]
    total = len(all_p) - 1
    for f in range(1, len(all_p)):
        for s in range(params.substeps):
            place(f, (s + 1) / params.substeps)
            data.qfrc_applied[dof3] = -drag * data.qvel[dof3]
            mujoco.mj_step(model, data)
        if f >= S:
            for k, out in enumerate(outs):
                out[f - S] = data.flexvert_xpos[adr[k]:adr[k] + out.shape[1]]
        if progress is not None:
            progress(f, total)
    seconds = time.perf_counter() - t_start
    return ClothRun(outs, motion.poses[:T].astype(np.float32), motion.trans[:T].astype(np.float32), seconds, S)


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
    params = params or SimParams()
    V0 = np.asarray(garment_vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    run = simulate_cloths([Cloth("cloth", V0, F)], body, motion, params, frames, settle_blend, settle_hold,
                          pin_top, hulls, progress)
    out, T, S = run.vertices[0], len(run.poses), run.settle_frames
    stats = sequence_stats(out, V0.astype(np.float32), F, body, run.poses, run.trans)
    stats["seconds"] = round(run.seconds, 3)
    stats["seconds_per_frame"] = round(run.seconds / (T + S), 4)
    return SimResult(out, run.poses, run.trans, params, stats, run.seconds, S)
