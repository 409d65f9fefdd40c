"""The served rig: at most 4 (or 8) skin influences per vertex, as engines play them, with blend shapes
refit so that it stays close to the network's dense rig.

DeePSD's weights head gives every vertex 24 non-zero weights (5-6 above 1%); three.js reads 4
influences a vertex, most engines 4 or 8. Keeping the k largest weights (renormalised) moves the posed
garment 2-6 mm on average from the dense rig; refitting the blend shapes recovers about half of it:
for fit poses (frames of the clips the network trained on), the dense rig's posed vertices are pulled
back into rest space through the sparse rig's blended rotations (LBS is affine in the rest position)
and the residual is regressed on the pose keys, one ridge solve shared by all vertices:

    D' = D + argmin_dD  sum_t || keys_t dD - A'_t^-1 (x_dense_t - x_sparse_t) ||^2 + lam T ||dD||^2

A sparse rig is a rig like any other: `pose_outfit` poses it and the GLB carries it exactly.
"""

from __future__ import annotations

import numpy as np

from drape.geometry.skeleton import forward_kinematics
from drape.runtime.deepsd import Rig, pose_outfit

INFLUENCES = (4, 8)  # what the service offers; 4 by default (three.js, most engines)
RIDGE = 1e-3
BLOCK_VERTEX_FRAMES = 400_000  # vertices x frames refit at once (64 frames up to 6,250 vertices)
SOLVE_COLUMNS = 16_384  # columns of the ridge solve at once (3 per vertex): 16 MB of float64 at 128 keys
FIT_FRAMES = 300  # 300 and 1,000 fit frames gave the same held-out figures (runs/sparse_rig_check.py)
# the embedded clips DeePSD trained on: all but its held-out evaluation clips (walk, kick, dance_b;
# tests/runtime/test_sparse_rig.py checks this against the training config)
FIT_CLIPS = ("backflip", "cartwheel", "crawl", "dance_a", "getup_facedown", "getup_faceup", "jump", "punch",
             "roll", "run", "spin", "spinkick")


def fit_poses(frames: int = FIT_FRAMES, seed: int = 0) -> np.ndarray:
    """(frames, 24, 3) rad: poses drawn (seeded, without repeats) from the FIT_CLIPS."""
    from drape.assets.motion import load_clip

    poses = np.concatenate([load_clip(c).poses for c in FIT_CLIPS]).astype(np.float64)
    pick = np.random.default_rng(seed).choice(len(poses), min(frames, len(poses)), replace=False)
    return poses[np.sort(pick)]


def top_weights(weights: np.ndarray, k: int) -> np.ndarray:
    """(N, K) weights -> (N, K) float32 keeping each row's k largest, renormalised to sum 1."""
    w = np.asarray(weights, dtype=np.float64)
    keep = np.argsort(-w, axis=1, kind="stable")[:, :k]
    out = np.zeros_like(w)
    rows = np.arange(len(w))[:, None]
    out[rows, keep] = w[rows, keep]
    return (out / out.sum(axis=1, keepdims=True)).astype(np.float32)


def _inverse3(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> inverses by cofactors (numpy's solve loops over tiny matrices one LAPACK call each)."""
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    d, e, f = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    g, h, i = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    co = np.stack([e * i - f * h, c * h - b * i, b * f - c * e,
                   f * g - d * i, a * i - c * g, c * d - a * f,
                   d * h - e * g, b * g - a * h, a * e - b * d], axis=-1).reshape(m.shape)
    det = a * co[..., 0, 0] + b * co[..., 1, 0] + c * co[..., 2, 0]
    return co / det[..., None, None]


def sparse_rig(rest_vertices: np.ndarray, rig: Rig, rest_joints: np.ndarray, influences: int,
               poses: np.ndarray, keys: np.ndarray, block: int = 64, targets: np.ndarray | None = None) -> Rig:
    """The dense `rig` of an outfit (rest_vertices (N, 3) m, on a body with rest_joints (24, 3) m) with
    at most `influences` weights per vertex and its blend shapes (P, N, 3) refit over the fit frames:
    poses (T, 24, 3) rad (e.g. `fit_poses()`), keys (T, P) their pose keys; targets (T, N, 3) m: what the
    sparse rig is fit to at those poses (default: the dense rig's posed vertices). -> Rig. A rig whose vertices
    already have at most `influences` weights each (a DeePSD trained with candidate joints) is returned as it
    is: pruning keeps every weight and there is nothing to refit."""
    if targets is None and np.count_nonzero(rig.weights, axis=1).max(initial=0) <= influences:
        return rig
    weights = top_weights(rig.weights, influences)
    sparse = Rig(weights, rig.blend_shapes)
    keys32 = np.asarray(keys, dtype=np.float32)
    keys64 = keys32.astype(np.float64)
    T, P = keys64.shape
    rhs = np.zeros((P, rig.blend_shapes.shape[1] * 3))
    w64 = weights.astype(np.float64)
    # frames a block: the (N, block, 3, 3) float64 blended rotations stay under ~30 MB at any vertex count
    block = max(1, min(block, BLOCK_VERTEX_FRAMES // max(len(rest_vertices), 1)))
    for s in range(0, T, block):  # the translation changes nothing here: none is applied
        p, k = poses[s:s + block], keys32[s:s + block]
        dense = pose_outfit(rest_vertices, rig, k, rest_joints, p) if targets is None else targets[s:s + block]
        moved = pose_outfit(rest_vertices, sparse, k, rest_joints, p)
        rot = forward_kinematics(p, rest_joints)[0][:, :, :3, :3]  # (t, K, 3, 3)
        blended = (w64 @ rot.transpose(1, 0, 2, 3).reshape(len(w64[0]), -1)).reshape(-1, len(p), 3, 3)
        diff = (dense - moved).astype(np.float64).transpose(1, 0, 2)  # (N, t, 3)
        # only where the target differs (a collision fit's targets move a few % of the vertex-frames)
        differs = np.any(diff != 0, axis=2)  # (N, t)
        residual = np.zeros_like(diff)
        inv = _inverse3(blended[differs])  # (D, 3, 3)
        residual[differs] = (inv * diff[differs][:, None, :]).sum(axis=2)
        residual = residual.transpose(1, 0, 2)  # (t, N, 3)
        rhs += keys64[s:s + block].T @ residual.reshape(len(p), -1)
    gram = keys64.T @ keys64 + RIDGE * T * np.eye(P)
    # solved a slice of columns at a time, in place, and added shape by shape: the whole (P, 3N) float64 solve
    # and sum held four copies of rhs (~560 MB for a 48k-vertex garment, bench.rig_scale); each column's solve is
    # its own, so the blend shapes are the same
    step = max(1, SOLVE_COLUMNS)
    for s in range(0, rhs.shape[1], step):
        rhs[:, s:s + step] = np.linalg.solve(gram, rhs[:, s:s + step])
    delta = rhs.reshape(P, -1, 3)
    shapes = np.empty(rig.blend_shapes.shape, np.float32)
    for shape in range(P):  # float32 + float64 is float64, rounded to float32 on assignment: (a + b).astype(float32)
        shapes[shape] = rig.blend_shapes[shape] + delta[shape]
    return Rig(weights, shapes)

