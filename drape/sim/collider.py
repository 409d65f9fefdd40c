"""The body collider: convex slabs of the skinned body, one rigid set per bone.

Each bone's vertices (skinning weight >= `min_weight`) are cut into slabs
`slab` metres thick along the bone, and each slab becomes the convex hull of its
points (MuJoCo collides mesh geoms as convex hulls). Thin slabs follow the
waist's and knees' concavities, which one hull per bone would bridge over. The
hulls are stored in rest-pose world coordinates; a kinematic body per bone carries
them with the bone's skinning transform, so x_posed = R_k x_rest + t_k.

Chosen by measurement over capsules (one or several per bone) on the neutral
body's pelvis, spine and legs: slab hulls cover the body's vertices and contain
only 7.8% of points 5 mm outside the skin; one fitted capsule per bone contains
99.6% of those points (capsules are far fatter than the body), so cloth would
hang centimetres off it. Printed by `tests/sim/test_collider.py`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from drape.assets.body import Body


@dataclass(frozen=True)
class Hull:
    """One convex piece: bone index and hull vertices (H, 3) float64, rest pose, metres."""

    bone: int
    vertices: np.ndarray


def _bone_axis(body: Body, k: int, points: np.ndarray) -> np.ndarray:
    """Unit direction of bone k: toward the mean of its children's joints, else the points' main axis."""
    children = [c for c in range(len(body.parents)) if body.parents[c] == k]
    if children:
        a = body.joints[children].astype(np.float64).mean(axis=0) - body.joints[k]
        if np.linalg.norm(a) > 0.03:
            return a / np.linalg.norm(a)
    _, _, vt = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
    return vt[0]


def fit_hulls(
    body: Body,
    bones: list[int] | None = None,
    slab: float = 0.05,
    min_weight: float = 0.3,
    overlap: float = 0.008,
) -> list[Hull]:
    """Convex slab hulls of the body, per bone (all 24 when bones is None); rest pose, metres."""
    V = body.vertices.astype(np.float64)
    hulls: list[Hull] = []
    for k in bones if bones is not None else range(len(body.parents)):
        P = V[body.weights[:, k] >= min_weight]
        if len(P) < 15:
            continue
        t = P @ _bone_axis(body, k, P)
        n = max(1, int(round(float(np.ptp(t)) / slab)))
        edges = np.linspace(t.min(), t.max(), n + 1)
        for i in range(n):
            Q = P[(t >= edges[i] - overlap) & (t <= edges[i + 1] + overlap)]
            if len(Q) < 8:
                continue
            try:
                h = ConvexHull(Q)
            except QhullError:  # a flat slab has no volume
                continue
            hulls.append(Hull(bone=int(k), vertices=Q[h.vertices]))
    return hulls


def inside_hulls(points: np.ndarray, hulls: list[Hull], tol: float = 0.0) -> np.ndarray:
    """points (P, 3) in rest pose -> (P,) bool: inside (or within tol of) any hull."""
    inside = np.zeros(len(points), dtype=bool)
    for h in hulls:
        eq = ConvexHull(h.vertices).equations
        inside |= ((points @ eq[:, :3].T + eq[:, 3]) <= tol).all(axis=1)
    return inside


def garment_bones(body: Body, garment_vertices: np.ndarray, reach: float = 0.15) -> list[int]:
    """Bones whose vertices come within `reach` metres of the garment (rest pose): the ones to collide with."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(garment_vertices).query(body.vertices, distance_upper_bound=reach)
    near = np.isfinite(d)
    return sorted({int(k) for k in np.unique(body.weights[near].argmax(axis=1))})
