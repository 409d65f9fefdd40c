"""Linear blend skinning, batched over frames."""

from __future__ import annotations

import numpy as np

from drape.geometry.skeleton import PARENTS, forward_kinematics


def linear_blend_skinning(
    rest_vertices: np.ndarray, weights: np.ndarray, transforms: np.ndarray
) -> np.ndarray:
    """Skin rest vertices with per-joint transforms.

    rest_vertices: (N, 3) or (T, N, 3) metres (per-frame rest shapes, e.g. with
    pose-space blend shapes added); weights: (N, K), rows summing to 1;
    transforms: (T, K, 4, 4) from `forward_kinematics`.
    Returns (T, N, 3) float32 metres.
    """
    w = np.asarray(weights, dtype=np.float32)
    tr = np.asarray(transforms, dtype=np.float32)
    T, K = tr.shape[:2]
    # blend the 3x4 affine parts: (T, N, 12) = (N, K) x (T, K, 12), one GEMM for all frames
    blended = np.einsum("nk,tkc->tnc", w, tr[..., :3, :].reshape(T, K, 12), optimize=True)
    blended = blended.reshape(T, -1, 3, 4)
    v = np.asarray(rest_vertices, dtype=np.float32)
    if v.ndim == 2:
        v = np.broadcast_to(v, (T,) + v.shape)
    return np.einsum("tnij,tnj->tni", blended[..., :3], v, optimize=True) + blended[..., 3]


def pose_mesh(
    rest_vertices: np.ndarray,
    weights: np.ndarray,
    rest_joints: np.ndarray,
    poses: np.ndarray,
    translation: np.ndarray | None = None,
    parents: np.ndarray = PARENTS,
) -> np.ndarray:
    """Forward kinematics then LBS: (N, 3) rest mesh + (T, K, 3) poses -> (T, N, 3) float32."""
    transforms, _ = forward_kinematics(poses, rest_joints, parents, translation)
    return linear_blend_skinning(rest_vertices, weights, transforms)


def smooth_weights(weights: np.ndarray, faces: np.ndarray, iterations: int = 20, step: float = 0.5) -> np.ndarray:
    """Diffuse skin weights (N, K) over a mesh's edges (uniform Laplacian steps); rows stay summing to 1.

    Used to soften weights copied from a body onto loose cloth (fewer tears between the legs).
    """
    from drape.geometry.mesh import uniform_laplacian

    w = np.asarray(weights, dtype=np.float64)
    lap = uniform_laplacian(faces, len(w))
    for _ in range(iterations):
        w = w - step * (lap @ w)
    w = np.clip(w, 0.0, None)
    return (w / np.maximum(w.sum(axis=1, keepdims=True), 1e-12)).astype(np.float32)


def rest_space_offsets(offsets: np.ndarray, weights: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """The rest-space offsets that linear blend skinning maps to given world-space offsets.

    LBS is affine in the rest position: p = sum_k w_k (R_k x + t_k), so moving x by d moves p by
    (sum_k w_k R_k) d. offsets: (n, 3) metres, world space, of n vertices at one frame; weights:
    (n, K) their skin weights; rotations: (K, 3, 3) the joints' skinning rotations at that frame
    (`forward_kinematics(...)[0][t, :, :3, :3]`). Returns d (n, 3) float32 metres.
    """
    blended = np.einsum("nk,kij->nij", np.asarray(weights, np.float64), np.asarray(rotations, np.float64))
    d = np.linalg.solve(blended, np.asarray(offsets, np.float64)[..., None])[..., 0]
    return d.astype(np.float32)
