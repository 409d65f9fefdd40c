"""The field's quality metrics for posed garments.

Shapes: garment vertices (T, N, 3) or (N, 3) metres (a single frame is treated
as T = 1); faces (F, 3); body vertices (T, M, 3) or (M, 3) matching the garment's
frames. Results are Python floats; lengths in millimetres where the name says so.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from drape.geometry.mesh import face_adjacency, face_normals, unique_edges, vertex_normals
from drape.geometry.queries import MeshDistance, signed_distance_nearest_vertex


def _frames(x: np.ndarray) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    return a[None] if a.ndim == 2 else a


def _paired_frames(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, N, 3) or (N, 3), (T, M, 3) or (M, 3) -> both (T, ., 3) float64: one frame on either side (a static
    body or layer) is paired with every frame of the other."""
    fa, fb = _frames(a), _frames(b)
    if len(fb) == 1 and len(fa) > 1:
        fb = np.broadcast_to(fb, (len(fa),) + fb.shape[1:])
    elif len(fa) == 1 and len(fb) > 1:
        fa = np.broadcast_to(fa, (len(fb),) + fa.shape[1:])
    return fa, fb


def collision_share(
    garment: np.ndarray,
    body_vertices: np.ndarray,
    body_faces: np.ndarray,
    variant: str = "triangle",
) -> float:
    """Share of garment vertices inside the body (signed distance < 0), over all frames.

    variant: "triangle" (exact closest point on the body's triangles) or
    "nearest_vertex" (DeePSD: offset to the nearest body vertex dotted with its normal).
    """
    g, b = _paired_frames(garment, body_vertices)
    inside = 0
    for gt, bt in zip(g, b, strict=True):
        if variant == "triangle":
            sd = MeshDistance(bt, body_faces).signed_distance(gt)
        elif variant == "nearest_vertex":
            sd, _ = signed_distance_nearest_vertex(gt, bt, vertex_normals(bt, body_faces))
        else:
            raise ValueError(f"unknown variant {variant!r}")
        inside += int(np.count_nonzero(sd < 0))
    return inside / (g.shape[0] * g.shape[1])


def edge_lengths(vertices: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(..., N, 3), (E, 2) -> (..., E) lengths."""
    v = np.asarray(vertices, dtype=np.float64)
    return np.linalg.norm(v[..., edges[:, 0], :] - v[..., edges[:, 1], :], axis=-1)


def edge_length_error_mm(vertices: np.ndarray, template: np.ndarray, faces: np.ndarray) -> float:
    """Mean |edge length - template edge length| in mm, over edges and frames."""
    e = unique_edges(faces)
    return float(np.mean(np.abs(edge_lengths(_frames(vertices), e) - edge_lengths(template, e))) * 1e3)


def max_edge_stretch(vertices: np.ndarray, template: np.ndarray, faces: np.ndarray) -> float:
    """Largest relative edge elongation (l / l_template - 1) over edges and frames."""
    e = unique_edges(faces)
    return float(np.max(edge_lengths(_frames(vertices), e) / edge_lengths(template, e)) - 1.0)


def bending(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Mean (1 - cosine) between the normals of faces that share an edge, over pairs and frames."""
    pairs = face_adjacency(faces)
    n = face_normals(_frames(vertices), faces)
    cos = np.einsum("tpc,tpc->tp", n[:, pairs[:, 0]], n[:, pairs[:, 1]])
    return float(np.mean(1.0 - cos))


def mean_vertex_error_mm(pred: np.ndarray, truth: np.ndarray) -> float:
    """Mean Euclidean per-vertex distance in mm between corresponding vertices."""
    return float(np.mean(np.linalg.norm(_frames(pred) - _frames(truth), axis=-1)) * 1e3)


def rmse_mm(pred: np.ndarray, truth: np.ndarray) -> float:
    """Root mean square per-vertex distance in mm."""
    d2 = np.sum((_frames(pred) - _frames(truth)) ** 2, axis=-1)
    return float(np.sqrt(np.mean(d2)) * 1e3)


def hausdorff_mm(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Hausdorff distance in mm between point sets, max over frames.

    a: (T, N, 3) or (N, 3); b: (T, M, 3) or (M, 3) (one frame on either side is compared with every frame of
    the other).
    """
    worst = 0.0
    for at, bt in zip(*_paired_frames(a, b), strict=True):
        d_ab = cKDTree(bt).query(at)[0].max()
        d_ba = cKDTree(at).query(bt)[0].max()
        worst = max(worst, float(d_ab), float(d_ba))
    return worst * 1e3


def sted(pred: np.ndarray, truth: np.ndarray, faces: np.ndarray, fps: float = 30.0) -> dict[str, float]:
    """Spatio-temporal edge difference (after Vasa & Skala 2011), a global variant.

    Spatial part: per frame, the standard deviation over edges of the relative
    edge-length difference (l_pred - l_true) / l_true, averaged over frames.
    Temporal part: mean over edges and frame pairs of the absolute difference of
    relative edge-length velocities, |dl_pred - dl_true| / l_true * fps (1/s).
    Combined: sqrt(spatial^2 + (temporal / fps)^2). Needs T >= 2 for the temporal part.
    """
    e = unique_edges(faces)
    lp, lt = edge_lengths(_frames(pred), e), edge_lengths(_frames(truth), e)
    rel = (lp - lt) / np.maximum(lt, 1e-12)
    spatial = float(np.mean(np.std(rel, axis=1)))
    if len(lp) >= 2:
        temporal = float(np.mean(np.abs(np.diff(lp, axis=0) - np.diff(lt, axis=0)) / np.maximum(lt[:-1], 1e-12)) * fps)
    else:
        temporal = 0.0
    return {"spatial": spatial, "temporal": temporal, "sted": float(np.hypot(spatial, temporal / fps))}


def layer_collision_share(
    outer: np.ndarray, inner: np.ndarray, inner_faces: np.ndarray
) -> float:
    """Share of outer-garment vertices on the inside of the inner garment's surface, over frames.

    outer: (T, N, 3) or (N, 3); inner: (T, M, 3) or (M, 3) with outward-facing faces (a single inner frame is
    every outer frame's; a single outer frame is measured against every inner frame).
    """
    inside = 0
    o, i = _paired_frames(outer, inner)
    for ot, it in zip(o, i, strict=True):
        inside += int(np.count_nonzero(MeshDistance(it, inner_faces).signed_distance(ot) < 0))
    return inside / (o.shape[0] * o.shape[1])
