"""The served rig's blend shapes fit to keep the garment out of its body, once per outfit at rig time.

DeePSD's physics training keeps most cloth out of the body, not all: on the validation split the sleeved
tops' cloth at the shoulders (the upper arm's skin) and the collar sinks 5-10 mm into the body (median over
inside vertices) on 2-6% of their vertices. A rig is linear in the pose keys, so a correction that depends on
the pose the way the network's blend shapes do can be fit by least squares: at fit poses, pose the rig, move
every garment vertex that is inside the body (by at most `DEEPEST`: deeper is a limb through the cloth, as a
leg through a skirt in a cartwheel, which no pose-linear correction should chase) or within `eps` of it onto the
closest body point + eps along the normal there (`pushed_targets`), and refit the blend shapes to the posed rig
moved `gain` times that push (`drape.runtime.sparse_rig.sparse_rig`, its ridge solve through the rig's own blended rotations; a least-squares
fit over many poses takes back part of every push, so a gain above 1 lands closer to the pushed cloth); `rounds`
times, each round from the rig the last gave. With the garment's faces the pushed targets are first relaxed toward
the rest edge lengths (`RELAX` Jacobi rounds, `drape.geometry.edge_relax`; the pushed vertices and the cloth within
`HOLD` of the body's vertices at rest held) and what that leaves within eps of the body pushed out again (`REPUSH`):
a pushed vertex alone would stretch its neighbours toward it (docs/deepsd_experiments.md, last section). Fit poses
(`fit_poses`): frames of the embedded clips and the procedural motions DeePSD trains on, never a validation or
evaluation motion.

The body is the part of its mesh within `reach` of the garment at rest (faces with a vertex that close),
posed by its own skin; closest points are those of the refinement (`drape.geometry.refine.BodySurface`; its second
reading with `far_k`). With `settle`, a pushed point that lands within 0.9 eps of another part of the body (under the
chin, at the armpit) is put out again from there, up to that many rounds.
Shapes: rest_vertices (N, 3) m; body vertices (M, 3) m, faces (G, 3), weights (M, 24), joints (24, 3) m;
poses (T, 24, 3) rad; keys (T, P).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from drape.geometry.edge_relax import relax_edges
from drape.geometry.mesh import coincident_groups, regroup_faces, unique_edges
from drape.geometry.metrics import edge_lengths
from drape.geometry.refine import BodySurface
from drape.runtime.deepsd import Rig, pose_outfit
from drape.runtime.sparse_rig import sparse_rig

if TYPE_CHECKING:
    from drape.assets.body import Body

EPS = 0.005  # m: the clearance a pushed vertex gets (DeePSD's training collision margin)
ROUNDS = 1
GAIN = 3.0
DEEPEST = 0.03  # m: a vertex deeper inside the body than this at a fit pose is not pushed (a limb through the cloth)
THREADS = 2
REACH = 0.1  # m: body faces farther than this from every garment vertex at rest are left out
# the served fit reads the body surface once and puts nothing out again (FAR_K None, SETTLE 0), as DeePSD 0.11.0's
# tables were measured; the second reading and 3 settle rounds (bench.deepsd_collision_fit's push_g3_r1_deep3_settle,
# docs/deepsd_experiments.md) are what a re-shipped rig would switch on
FAR_K: int | None = None
SETTLE = 0
# the fit's edge relaxation, chosen on the validation split (bench.deepsd_collision_fit's
# push_g3_r1_deep3_relax20h_repush): rounds (0: none), then what it leaves near the body pushed out again
RELAX = 20
REPUSH = True
FIT_BLOCK_VERTEX_FRAMES = 1_000_000  # vertex-frames of the targets made at once: all 150 fit frames up to 6,666 vertices
HOLD: float | None = 0.015  # m: cloth this near the body's vertices at rest is held by the relaxation
# fit poses: every 4th of the sparse rig's 300 (frames of the embedded clips DeePSD trained on) and every 12th frame
# of three of its procedural training motions (drape.training.deepsd_data: seeds 500 + i, 300 frames)
CLIP_STRIDE = 4
PROCEDURAL_SEEDS = (501, 502, 503)
PROCEDURAL_STRIDE = 12
# and every 12th frame of procedural motions with a captured skeleton's posture (drape.assets.procedural's
# `posture`: real mocap's upper-back and clavicle rotations, which the motions above never make), seeds 504 + i
POSTURE_MOTIONS = 0
POSTURE_SEED = 504


def posture_poses(motions: int) -> np.ndarray:
    """(25 x motions, 24, 3) rad: every PROCEDURAL_STRIDE-th frame of `motions` procedural motions (300 frames)
    with real mocap's posture, seeds POSTURE_SEED + i."""
    from drape.assets.procedural import generate_motion

    return np.concatenate([np.zeros((0, 24, 3))] + [
        generate_motion(300, seed=POSTURE_SEED + i, posture=1.0).poses[::PROCEDURAL_STRIDE] for i in range(motions)])


def fit_poses(posture_motions: int = POSTURE_MOTIONS) -> np.ndarray:
    """(150 + 25 x posture_motions, 24, 3) rad: the collision fit's poses."""
    from drape.assets.procedural import generate_motion
    from drape.runtime.sparse_rig import fit_poses as clip_poses

    procedural = np.concatenate([generate_motion(300, seed=s).poses for s in PROCEDURAL_SEEDS])
    return np.concatenate([clip_poses()[::CLIP_STRIDE], procedural[::PROCEDURAL_STRIDE],
                           posture_poses(posture_motions)]).astype(np.float64)


def body_near(rest_vertices: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray,
              reach: float = REACH) -> tuple[np.ndarray, np.ndarray]:
    """The body's faces with a vertex within `reach` of the garment at rest -> (used body vertex indices (S,),
    those faces (G', 3) re-indexed into them)."""
    d = cKDTree(np.asarray(rest_vertices, dtype=np.float64)).query(np.asarray(body_vertices, dtype=np.float64),
                                                                    distance_upper_bound=reach)[0]
    faces = np.asarray(body_faces, dtype=np.int64)
    keep = faces[np.isfinite(d)[faces].any(axis=1)]
    used, local = np.unique(keep, return_inverse=True)
    return used, local.reshape(keep.shape)


def pushed_targets(rest_vertices: np.ndarray, rig: Rig, rest_joints: np.ndarray, poses: np.ndarray,
                   keys: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray, body_weights: np.ndarray,
                   eps: float = EPS, reach: float = REACH, tight: tuple[float, float] | None = None,
                   deepest: float | None = None, threads: int = THREADS, far_k: int | None = FAR_K,
                   settle: int = SETTLE, start: np.ndarray | None = None) -> np.ndarray:
    """The rig posed at `poses` (no translation; or `start` (T, N, 3) m, points given at those poses) with every
    vertex closer to the body than eps (or inside it) moved onto its closest body point + eps along the body's
    normal there -> (T, N, 3) float32 m.
    far_k: the body surface's second reading (drape.geometry.refine.BodySurface; None: one reading).
    settle: rounds in which a moved point that lands nearer than 0.9 eps to the body (put off one part's surface
    into another's reach: under the chin, at the armpit) goes again to its new closest point + eps.
    tight = (near, far) m: only cloth that lies on the body at rest is pushed: a vertex nearer than `near` to the
    body's vertices at rest fully, one farther than `far` not at all, linearly between. deepest (m): a vertex
    deeper inside than this is left where it is (a limb through the cloth, not cloth sunk into the skin).
    threads: frames queried at once (the answer does not depend on it)."""
    posed = (pose_outfit(rest_vertices, rig, keys, rest_joints, poses) if start is None
             else np.array(start, dtype=np.float32))
    share = np.ones(len(posed[0]))
    if tight is not None:
        rest_gap = cKDTree(np.asarray(body_vertices, dtype=np.float64)).query(np.asarray(rest_vertices, np.float64))[0]
        share = np.clip((tight[1] - rest_gap) / (tight[1] - tight[0]), 0.0, 1.0)
    used, faces = body_near(rest_vertices, body_vertices, body_faces, reach)
    if len(used) == 0:
        return posed
    skin = Rig(np.asarray(body_weights, dtype=np.float32)[used], np.zeros((1, len(used), 3), dtype=np.float32))
    bodies = pose_outfit(np.asarray(body_vertices)[used], skin, np.zeros((len(poses), 1), dtype=np.float32),
                         rest_joints, poses)
    surface = BodySurface(faces, len(used), far_k=far_k)
    # settle asks the one reading: its points lie eps off the surface, where the second reading would be asked for most
    once = BodySurface(faces, len(used)) if far_k is not None and settle else surface

    def push(t: int) -> None:  # frame t in place; frames are independent
        b, x = bodies[t].astype(np.float64), posed[t].astype(np.float64)
        normals = surface.normals(b)
        sd, cp, n = surface.query(b, normals, x)
        near = (sd < eps) & (share > 0)
        if deepest is not None:
            near &= sd > -deepest
        target = cp[near] + eps * n[near]
        check = np.arange(len(target))  # settle: the points put out in the last round, asked again
        for _ in range(settle):
            again, c2, n2 = once.query(b, normals, target[check])
            close = again < 0.9 * eps
            check = check[close]
            if len(check) == 0:
                break
            target[check] = c2[close] + eps * n2[close]
        posed[t, near] = x[near] + share[near, None] * (target - x[near])

    if threads > 1:  # the KD-tree queries and numpy's larger passes release the GIL
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(push, range(len(posed))))
    else:
        for t in range(len(posed)):
            push(t)
    return posed


def collision_fit(rest_vertices: np.ndarray, rig: Rig, rest_joints: np.ndarray, influences: int,
                  poses: np.ndarray, keys: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray,
                  body_weights: np.ndarray, eps: float = EPS, rounds: int = ROUNDS, gain: float = GAIN,
                  reach: float = REACH, deepest: float | None = DEEPEST, faces: np.ndarray | None = None,
                  relax: int = RELAX, repush: bool = REPUSH, hold: float | None = HOLD, far_k: int | None = FAR_K,
                  settle: int = SETTLE, tight: tuple[float, float] | None = None,
                  stretch_only: bool = False) -> Rig:
    """`rig` with at most `influences` weights per vertex and its blend shapes refit, `rounds` times, to its own
    posed vertices moved `gain` times their push out of the body (`pushed_targets`, with its deepest, far_k,
    settle and tight) at the fit poses -> Rig.
    relax (with the garment's faces (F, 3)): that many rounds of edge-length relaxation toward the rest mesh's
    lengths (`drape.geometry.edge_relax`, its stretch_only) on the targets, before the refit; the pushed vertices
    are held, and with `hold` (m) every vertex nearer than that to the body's vertices at rest (cloth lying on the
    body); with `repush`, what the relaxation leaves within eps of the body (or inside) is pushed out once more
    (gain 1)."""
    welded = None
    if relax and faces is not None:  # relaxed on the welded mesh, so that coincident vertices (UV seams) stay one
        first, group = coincident_groups(rest_vertices)
        edges = unique_edges(regroup_faces(np.asarray(faces), group))
        welded = first, group, edges, edge_lengths(np.asarray(rest_vertices)[first], edges)
    on_body = np.zeros(len(rest_vertices), dtype=bool)
    if welded is not None and hold is not None:
        on_body = cKDTree(np.asarray(body_vertices, np.float64)).query(np.asarray(rest_vertices, np.float64))[0] < hold
    out = rig

    def push(points: np.ndarray, frames: slice) -> np.ndarray:  # points (t, N, 3) at those fit poses, pushed out
        return pushed_targets(rest_vertices, out, rest_joints, poses[frames], keys[frames], body_vertices, body_faces,
                              body_weights, eps, reach, tight=tight, deepest=deepest, far_k=far_k, settle=settle,
                              start=points)

    # the targets are made FIT_BLOCK frames at a time (each frame's push and relaxation is its own): the
    # float64 working arrays of every fit frame at once held ~1 GB for a 48k-vertex garment (bench.rig_scale)
    frames = len(poses)
    block = max(1, FIT_BLOCK_VERTEX_FRAMES // max(len(rest_vertices), 1))
    for _ in range(rounds):
        targets = np.empty((frames, len(rest_vertices), 3), np.float32)
        for s in range(0, frames, block):
            part = slice(s, s + block)
            posed = pose_outfit(rest_vertices, out, keys[part], rest_joints, poses[part])
            pushed = push(posed, part)
            target = posed + np.float32(gain) * (pushed - posed)
            if welded is not None:
                first, group, edges, rest = welded
                moved = np.any(pushed != posed, axis=2) | on_body[None]  # the same for coincident vertices
                target = relax_edges(target[:, first], edges, rest, relax, fixed=moved[:, first],
                                     stretch_only=stretch_only)[:, group]
                if repush:  # what the relaxation drew back into the body (or within eps of it) put out again
                    target = push(target, part)
            targets[part] = target
        out = sparse_rig(rest_vertices, out, rest_joints, influences, poses, keys, targets=targets)
    return out


Frames = tuple[np.ndarray, np.ndarray]  # fit poses (T, 24, 3) rad and their pose keys (T, P)


def served_fit_frames(pose_keys: Callable[[np.ndarray], np.ndarray]) -> tuple[Frames, Frames]:
    """What `served_rig` fits on, with a model's pose keys: (the sparse rig's fit frames, the collision fit's)."""
    from drape.runtime.sparse_rig import fit_poses as clip_poses

    sparse, collision = clip_poses(), fit_poses()
    return (sparse, pose_keys(sparse)), (collision, pose_keys(collision))


def served_rig(rest_vertices: np.ndarray, dense: Rig, body: Body, influences: int,
               sparse_fit: Frames, collision: Frames | None, faces: np.ndarray | None = None) -> Rig:
    """What the service serves for a network's `dense` rig of an outfit (rest_vertices (N, 3) m) on `body`: at
    most `influences` weights per vertex (`sparse_rig` at sparse_fit = (poses, keys)), then, unless `collision` is
    None, the collision fit at collision = (poses, keys) (`fit_poses` and their pose keys; both from
    `served_fit_frames`); faces (F, 3): the outfit's, for the fit's edge relaxation (`RELAX`; none without them)."""
    rig = sparse_rig(rest_vertices, dense, body.joints, influences, *sparse_fit)
    if collision is None:
        return rig
    return collision_fit(rest_vertices, rig, body.joints, influences, *collision, body.vertices, body.faces,
                         body.weights, faces=faces)
