"""Refinement between two garment layers (MGN's L-Coll; issue 22 item 4): each layer is pushed out of the
body, then the outer layer is pushed out of the inner one, by the same Laplacian-preserving solver
(`drape.geometry.refine.Refiner`), with the inner layer as the collider.

Order per frame: the inner against the body; the outer against the body; the outer against the inner; the
outer against the body once more (pushed along the inner's normals, where the inner folds, the armpit, the
outer can meet the body again). The report counts what each pass saw.

The inner layer is an open, thin surface, not a solid: `LayerSurface` is the refinement's collider
(`refine.BodySurface`) over the inner mesh with three changes.
- It is offset by the inner's thickness H_in along the inner's normals: an outer vertex closer than H_in to
  the inner's mid-surface counts as inside and is put at H_in + eps from it (MGN conditions the outer on
  H_in; the two-layer simulation keeps the same gap, drape.sim.layers).
- A point whose nearest inner vertex lies on the inner's boundary (hem, cuff, neckline, an open front) is
  outside: past an edge the closest point is the edge itself, where no side is defined (as the two-layer
  simulation's quality check, drape.sim.quality.outer_inner_distance, leaves such points unjudged).
- A point more than `band` behind the inner layer is outside: there the closest inner point is on the
  garment's far side (a jacket's back seen from a shirt's front), not the part it went through.

Shapes: inner (T, Ni, 3), outer (T, No, 3) metres; faces (F, 3) int; body (T, M, 3) metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from drape.geometry.mesh import boundary_edges
from drape.geometry.refine import (
    EPS,
    MAX_ITERATIONS,
    RELIEF_ITERATIONS,
    BodySurface,
    Refiner,
    RefineReport,
)

LAYER_EPS = 0.001  # metres kept beyond the inner layer's thickness
BAND = 0.03  # metres behind the inner layer beyond which a point is not judged


class LayerSurface(BodySurface):
    """The inner layer as a collider, offset by its thickness (m); see the module's docstring.

    faces (F, 3) and num_vertices: the inner mesh's topology; its posed vertices are passed to `query` (as
    `body`) per frame."""

    def __init__(self, faces: np.ndarray, num_vertices: int, thickness: float, band: float = BAND,
                 k: int = 2, far: float = 0.015):
        super().__init__(faces, num_vertices, k=k, far=far + thickness)
        self.thickness, self.band = float(thickness), float(band)
        self.boundary = np.zeros(num_vertices, dtype=bool)
        self.boundary[boundary_edges(np.asarray(faces, dtype=np.int64)).ravel()] = True

    def query(self, body: np.ndarray, normals: np.ndarray, points: np.ndarray,
              tree: cKDTree | None = None, k: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """points (P, 3) -> (signed distance to the offset surface (P,), closest point on it (P, 3), normal)."""
        sd, cp, n, near = self._query(body, normals, points, tree, k)
        unjudged = self.boundary[near] | (sd < -self.band)
        sd = np.where(unjudged, np.maximum(np.abs(sd), self.thickness + 1e-6), sd) - self.thickness
        return sd, cp + self.thickness * n, n


@dataclass
class LayerReport:
    """Per frame: vertices inside the body before/after for each layer, and outer vertices closer to the inner
    layer than its thickness (or behind it) before/after, as the refiners' own queries count them."""

    inner_in_body_before: list[int] = field(default_factory=list)
    inner_in_body_after: list[int] = field(default_factory=list)
    outer_in_body_before: list[int] = field(default_factory=list)
    outer_in_body_after: list[int] = field(default_factory=list)
    outer_in_inner_before: list[int] = field(default_factory=list)
    outer_in_inner_after: list[int] = field(default_factory=list)


class LayerRefiner:
    """Refinement of a two-layer garment stream; built once per pair of topologies and thickness.

    inner_faces (Fi, 3), outer_faces (Fo, 3): the layers' topologies; thickness: H_in, metres;
    body_faces (G, 3) and body_vertices: the body's topology and vertex count; eps: metres kept from the body;
    max_iterations, relief_iterations: as refine.Refiner's, for every pass."""

    def __init__(self, inner_faces: np.ndarray, num_inner: int, outer_faces: np.ndarray, num_outer: int,
                 thickness: float, body_faces: np.ndarray, body_vertices: int, eps: float = EPS,
                 max_iterations: int = MAX_ITERATIONS, relief_iterations: int = RELIEF_ITERATIONS):
        it, relief = max_iterations, relief_iterations
        self.inner = Refiner(inner_faces, num_inner, eps=eps, max_iterations=it, relief_iterations=relief)
        self.outer = Refiner(outer_faces, num_outer, eps=eps, max_iterations=it, relief_iterations=relief)
        self.between = Refiner(outer_faces, num_outer, eps=LAYER_EPS, max_iterations=it, relief_iterations=relief)
        self.body_surface = BodySurface(body_faces, body_vertices)
        self.layer_surface = LayerSurface(inner_faces, num_inner, thickness)

    def refine_frame(self, inner: np.ndarray, outer: np.ndarray, body: np.ndarray, report: LayerReport,
                     stages: list[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """inner (Ni, 3), outer (No, 3), body (M, 3) -> (inner, outer) refined, float64; appends to `report`, and
        to `stages` (where given) the outer after each of its three passes (bench.layers_refine_passes)."""
        r = RefineReport()
        inner = self.inner.refine_frame(inner, body, self.body_surface, r)
        outer = self.outer.refine_frame(outer, body, self.body_surface, r)
        if stages is not None:
            stages.append(outer)
        outer = self.between.refine_frame(outer, inner, self.layer_surface, r)
        if stages is not None:
            stages.append(outer)
        # pushed along the inner's normals, where the inner folds (the armpit) the outer can meet the body again
        outer = self.outer.refine_frame(outer, body, self.body_surface, r)
        if stages is not None:
            stages.append(outer)
        report.inner_in_body_before.append(r.inside_before[0])
        report.inner_in_body_after.append(r.inside_after[0])
        report.outer_in_body_before.append(r.inside_before[1])
        report.outer_in_body_after.append(r.inside_after[3])
        report.outer_in_inner_before.append(r.inside_before[2])
        report.outer_in_inner_after.append(r.inside_after[2])
        return inner, outer


def refine_layers(inner: np.ndarray, inner_faces: np.ndarray, outer: np.ndarray, outer_faces: np.ndarray,
                  body: np.ndarray, body_faces: np.ndarray, thickness: float, eps: float = EPS,
                  ) -> tuple[np.ndarray, np.ndarray, LayerReport]:
    """Refine a two-layer stream: inner (T, Ni, 3), outer (T, No, 3), body (T, M, 3) metres, thickness (H_in, m)
    -> (inner (T, Ni, 3) float32, outer (T, No, 3) float32, report)."""
    refiner = LayerRefiner(inner_faces, inner.shape[1], outer_faces, outer.shape[1], thickness, body_faces,
                           body.shape[1], eps=eps)
    report = LayerReport()
    pairs = [refiner.refine_frame(i, o, b, report) for i, o, b in zip(inner, outer, body, strict=True)]
    return (np.stack([p[0] for p in pairs]).astype(np.float32), np.stack([p[1] for p in pairs]).astype(np.float32),
            report)
