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


MIN_BLEND_DET = 1e-2  # |det| of a blended skinning rotation below this: weights mixing rotations ~170 deg apart


def invertible_blends(blended: np.ndarray) -> np.ndarray:
    """(n, 3, 3) blended skinning rotations -> (n,) bool: |det| >= MIN_BLEND_DET (False for NaN too)."""
    return np.abs(np.linalg.det(blended)) >= MIN_BLEND_DET


def rest_space_offsets(offsets: np.ndarray, weights: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """The rest-space offsets that linear blend skinning maps to given world-space offsets.

    LBS is affine in the rest position: p = sum_k w_k (R_k x + t_k), so moving x by d moves p by
    (sum_k w_k R_k) d. offsets: (n, 3) metres, world space, of n vertices at one frame; weights:
    (n, K) their skin weights; rotations: (K, 3, 3) the joints' skinning rotations at that frame
    (`forward_kinematics(...)[0][t, :, :3, :3]`). Returns d (n, 3) float32 metres. Where the blend is
    singular or nearly (|det| < MIN_BLEND_DET: weights mixing rotations about half a turn apart, e.g. an elbow
    bent all the way), no rest offset gives the move: d is the least-squares one (pseudo-inverse).
    """
    blended = np.einsum("nk,kij->nij", np.asarray(weights, np.float64), np.asarray(rotations, np.float64))
    offsets = np.asarray(offsets, np.float64)
    invertible = invertible_blends(blended)
    d = np.empty_like(offsets)
    d[invertible] = np.linalg.solve(blended[invertible], offsets[invertible][..., None])[..., 0]
    if not invertible.all():
        d[~invertible] = (np.linalg.pinv(blended[~invertible], rcond=1e-3) @ offsets[~invertible][..., None])[..., 0]
    return d.astype(np.float32)


class SingularSkinning(ValueError):
    """Some vertices' blended skinning transforms cannot be inverted: their weights mix joint rotations that
    (nearly) cancel, so no rest position maps to where they are posed."""


def unskin(blended: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Invert per-vertex blended skinning transforms: blended (N, 4, 4) rest -> posed, points (N, 3) metres posed
    -> (N, 3) float64 metres at rest. Raises SingularSkinning where |det| of a blended rotation part is under
    MIN_BLEND_DET (the inverse would throw the vertex metres away, or fail)."""
    blended = np.asarray(blended, dtype=np.float64)
    bad = ~invertible_blends(blended[:, :3, :3])
    if bad.any():
        raise SingularSkinning(f"{int(bad.sum())} of {len(bad)} vertices' skinning cannot be undone in this pose: "
                               f"their weights mix joint rotations that cancel (|det| under {MIN_BLEND_DET:g})")
    homo = np.concatenate([np.asarray(points, dtype=np.float64), np.ones((len(points), 1))], axis=1)
    return np.linalg.solve(blended, homo[..., None])[:, :3, 0]


def unpose_body(
    vertices: np.ndarray,
    weights: np.ndarray,
    joints: np.ndarray,
    pose: np.ndarray,
    parents: np.ndarray = PARENTS,
) -> tuple[np.ndarray, np.ndarray]:
    """A body given in `pose` -> the same body in its rest (T-) pose, by inverting its own skinning.

    vertices: (V, 3) metres, as posed; weights: (V, K) rows summing to 1; joints: (K, 3) metres, as posed;
    pose: (K, 3) axis-angle radians, each joint's local rotation away from the rest pose; parents: (K,),
    every parent lower than its child. Returns (rest vertices (V, 3), rest joints (K, 3)) float64 metres,
    such that `pose_mesh(rest vertices, weights, rest joints, pose[None])` gives `vertices` back.
    Bone vectors keep their lengths: rest_k = rest_p + R_p^T (posed_k - posed_p), with R_p the parent's
    accumulated rotation (the pose is taken about the root joint, so the root does not move).
    """
    pose = np.asarray(pose, dtype=np.float64).reshape(1, -1, 3)
    posed = np.asarray(joints, dtype=np.float64)
    zero = np.zeros_like(posed)
    world_rot = forward_kinematics(pose, zero, parents)[0][0, :, :3, :3]  # (K, 3, 3) accumulated rotations
    rest = np.empty_like(posed)
    for k in range(len(posed)):
        p = int(parents[k])
        rest[k] = posed[k] if p < 0 else rest[p] + world_rot[p].T @ (posed[k] - posed[p])
    transforms = forward_kinematics(pose, rest, parents)[0][0]  # (K, 4, 4) rest -> posed
    blended = np.einsum("vk,kij->vij", np.asarray(weights, dtype=np.float64), transforms)
    return unskin(blended, vertices), rest
