"""Refinement between two garment layers (MGN's L-Coll; issue 22 item 4): each layer is pushed out of the
body, then the outer layer is pushed out of the inner one, by the same Laplacian-preserving solver
(`drape.geometry.refine.Refiner`), with the inner layer as the collider.

Order per frame: the inner against the body; the outer against the body; the outer against the inner; the
outer against the body and the inner as one collider (`BodyAndLayerSurface`: pushed along the inner's normals,
where the inner folds, the armpit, the outer can meet the body again, and pushed out of the body it can land
behind the inner). The inner's pass and the last one end with the refiner's last check (`verify_k`), which finds
points inside where the body overlaps itself. The report counts what each pass saw.
(`bench.layers_refine_passes` measures each pass; docs/layers.md has the table.)

The inner layer is an open, thin surface, not a solid: `LayerSurface` is the refinement's collider over the
inner mesh, answering as `refine.BodySurface` answers for the body, with exact distances and sides (the closest
point on the inner's triangles, the side by the pseudo-normal there: `queries.OpenSurfaceDistance`, the measure
the simulation's quality check and L-Coll use) and three rules.
- It is offset by the inner's thickness H_in along the inner's normals: an outer vertex closer than H_in to
  the inner's mid-surface counts as inside and is put at H_in + eps from it (MGN conditions the outer on
  H_in; the two-layer simulation keeps the same gap, drape.sim.layers).
- A point whose closest inner point lies on the inner's boundary (hem, cuff, neckline, an open front) is
  outside: past an edge the closest point is the edge itself, where no side is defined (as the two-layer
  simulation's quality check, drape.sim.quality.outer_inner_distance, leaves such points unjudged).
- A point more than `band` behind the inner layer is outside: there the closest inner point is on the
  garment's far side (a jacket's back seen from a shirt's front), not the part it went through.

Shapes: inner (T, Ni, 3), outer (T, No, 3) metres; faces (F, 3) int; body (T, M, 3) metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drape.geometry.nearest import VertexTree
from drape.geometry.queries import OpenSurfaceDistance
from drape.geometry.refine import (
    EPS,
    FAR_K,
    MAX_ITERATIONS,
    RELIEF_ITERATIONS,
    BodySurface,
    Refiner,
    RefineReport,
    body_tree,
)

LAYER_EPS = 0.001  # metres kept beyond the inner layer's thickness
BAND = 0.03  # metres behind the inner layer beyond which a point is not judged
LAYER_VERIFY_K = 8  # the last check of the inner's pass and the outer's last pass (refine.Refiner's verify_k)
# ... which does not take a place whose edges to the neighbours exceed this many times the vertex's longest edge
# in the input (refine.Refiner's verify_stretch): on the served t-shirt + jacket along the real walk it put jacket
# vertices out of the armpit 6-15 cm away (edges 4-70x longer; outer STED 0.24 -> 0.39 where the passes without
# the check give 0.25); with it, STED 0.34 and both collision shares still <= 0.1%
LAYER_VERIFY_STRETCH = 3.0


class LayerSurface:
    """The inner layer as a collider, offset by its thickness (m); see the module's docstring.

    faces (F, 3) and num_vertices: the inner mesh's topology; its posed vertices are passed to `normals` and
    `query` (as `body`) per frame, as `refine.Refiner` passes a body to a `refine.BodySurface`. Distances and sides
    are exact (`OpenSurfaceDistance`: the closest point on the inner's triangles, the side by the pseudo-normal
    there), the same measure as the simulation's quality check, so what the refinement counts as inside is what
    L-Coll counts."""

    def __init__(self, faces: np.ndarray, num_vertices: int, thickness: float, band: float = BAND,
                 exact: bool = True):
        self.thickness, self.band, self.exact = float(thickness), float(band), exact
        self.distance = OpenSurfaceDistance(faces, num_vertices, reach=max(self.band, self.thickness) + 0.01)
        self._posed: np.ndarray | None = None

    def _frame(self, body: np.ndarray) -> None:
        if body is not self._posed:
            self.distance.frame(body)
            self._posed = body

    def normals(self, body: np.ndarray) -> np.ndarray:
        """Posed inner vertices (Ni, 3) -> unit angle-weighted vertex normals (Ni, 3); sets the frame `query` uses."""
        self._frame(body)
        return self.distance.normals[2]

    def query(self, body: np.ndarray, normals: np.ndarray, points: np.ndarray,
              tree: VertexTree | None = None, k: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """points (P, 3) -> (signed distance to the offset surface (P,), closest point on it (P, 3), normal).
        normals, tree and k are the body collider's arguments, unused here."""
        self._frame(body)
        sd, cp, n, covered = self.distance.query(points, exact=self.exact)
        unjudged = ~covered | (sd < -self.band)
        sd = np.where(unjudged, np.maximum(np.abs(sd), self.thickness + 1e-6), sd) - self.thickness
        return sd, cp + self.thickness * n, n


class BodyAndLayerSurface:
    """The body and the inner layer as one collider, for the outer layer's last pass: each point answers for the
    surface it is deeper inside (the smaller signed distance), so a vertex pushed out of the body cannot land behind
    the inner layer, nor one pushed out of the inner layer inside the body.

    The refiner passes one array as `body`: the posed body's vertices (M, 3) followed by the posed inner's (Ni, 3).
    Its refiner keeps LAYER_EPS (the pass against the inner layer's); the body part is offset by `body_eps` -
    LAYER_EPS along its normals, so that a vertex pushed out of the body keeps `body_eps` from it, as the body
    passes do."""

    def __init__(self, body_surface: BodySurface, num_body: int, inner_faces: np.ndarray, num_inner: int,
                 thickness: float, body_eps: float = EPS):
        self.body, self.m = body_surface, int(num_body)
        self.layer = LayerSurface(inner_faces, num_inner, thickness, exact=False)
        self.shift = float(body_eps) - LAYER_EPS
        self._posed: np.ndarray | None = None

    def parts(self, both: np.ndarray) -> tuple[np.ndarray, np.ndarray, VertexTree, np.ndarray, np.ndarray]:
        """Body then inner vertices (M + Ni, 3) -> (body (M, 3), its normals, its KD-tree, inner (Ni, 3), its
        normals), built once per frame."""
        if both is not self._posed:
            b, i = both[:self.m], both[self.m:]
            self._parts = (b, self.body.normals(b), body_tree(b), i, self.layer.normals(i))
            self._posed = both
        return self._parts

    def normals(self, body: np.ndarray) -> np.ndarray:
        """Body then inner vertices (M + Ni, 3) -> their unit normals (M + Ni, 3); sets the frame `query` uses."""
        parts = self.parts(body)
        return np.concatenate([parts[1], parts[4]])

    def query(self, body: np.ndarray, normals: np.ndarray, points: np.ndarray,
              tree: VertexTree | None = None, k: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """points (P, 3) -> (signed distance (P,), closest point (P, 3), normal (P, 3)) of the surface each point is
        deeper inside; normals and tree are unused (each part keeps its own), k goes to the body's query."""
        b, bn, bt, i, ln = self.parts(body)
        sb, cb, nb = self.body.query(b, bn, points, bt, k)
        sb, cb = sb - self.shift, cb + self.shift * nb
        sl, cl, nl = self.layer.query(i, ln, points)
        layer = sl < sb
        return np.where(layer, sl, sb), np.where(layer[:, None], cl, cb), np.where(layer[:, None], nl, nb)


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


def inner_refiner(inner_faces: np.ndarray, num_inner: int, eps: float = EPS, max_iterations: int = MAX_ITERATIONS,
                  relief_iterations: int = RELIEF_ITERATIONS, verify_k: int = LAYER_VERIFY_K) -> Refiner:
    """The post step's inner pass (`LayerRefiner`'s first): the inner garment (Fi, 3) faces against the body,
    queried on `BodySurface(body_faces, body_vertices, far_k=FAR_K)`."""
    return Refiner(inner_faces, num_inner, eps=eps, max_iterations=max_iterations,
                   relief_iterations=relief_iterations, verify_k=verify_k, verify_stretch=LAYER_VERIFY_STRETCH)


class LayerRefiner:
    """Refinement of a two-layer garment stream; built once per pair of topologies and thickness.

    inner_faces (Fi, 3), outer_faces (Fo, 3): the layers' topologies; thickness: H_in, metres;
    body_faces (G, 3) and body_vertices: the body's topology and vertex count; eps: metres kept from the body;
    max_iterations, relief_iterations: as refine.Refiner's, for every pass; verify_k: the last check
    (refine.Refiner's `verify_k`: the body's faces around that many nearest vertices, where the body overlaps
    itself) of the inner's pass and of the outer's last pass."""

    def __init__(self, inner_faces: np.ndarray, num_inner: int, outer_faces: np.ndarray, num_outer: int,
                 thickness: float, body_faces: np.ndarray, body_vertices: int, eps: float = EPS,
                 max_iterations: int = MAX_ITERATIONS, relief_iterations: int = RELIEF_ITERATIONS,
                 verify_k: int = LAYER_VERIFY_K):
        it, relief = max_iterations, relief_iterations
        self.inner = inner_refiner(inner_faces, num_inner, eps, it, relief, verify_k)
        self.outer = Refiner(outer_faces, num_outer, eps=eps, max_iterations=it, relief_iterations=relief)
        # the between pass's last check takes no place whose edges exceed LAYER_VERIFY_STRETCH either: without
        # the cap it put jacket vertices out of a fold of the t-shirt across it (kick's frame 32: an edge 19 cm
        # longer, 38 mm with the cap; tests/geometry/test_layers.py; a probe's frame: 12 cm)
        self.between = Refiner(outer_faces, num_outer, eps=LAYER_EPS, max_iterations=it, relief_iterations=relief,
                               verify_stretch=LAYER_VERIFY_STRETCH)
        self.last = Refiner(outer_faces, num_outer, eps=LAYER_EPS, max_iterations=it, relief_iterations=relief,
                            verify_k=verify_k, verify_stretch=LAYER_VERIFY_STRETCH)
        self.body_surface = BodySurface(body_faces, body_vertices, far_k=FAR_K)
        self.layer_surface = LayerSurface(inner_faces, num_inner, thickness, exact=False)
        self.both_surface = BodyAndLayerSurface(self.body_surface, body_vertices, inner_faces, num_inner, thickness,
                                                body_eps=eps)

    def refine_frame(self, inner: np.ndarray, outer: np.ndarray, body: np.ndarray, report: LayerReport | None,
                     stages: list[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """inner (Ni, 3), outer (No, 3), body (M, 3) -> (inner, outer) refined, float64; appends to `report` (None:
        no report, and the outer's two counts after the last pass are not queried), and to `stages` (where given)
        the outer after each of its three passes (bench.layers_refine_passes)."""
        r = RefineReport()
        body = np.asarray(body, dtype=np.float64)
        inner = self.inner.refine_frame(inner, body, self.body_surface, r)
        outer = self.outer.refine_frame(outer, body, self.body_surface, r)
        if stages is not None:
            stages.append(outer)
        outer = self.between.refine_frame(outer, inner, self.layer_surface, r)
        if stages is not None:
            stages.append(outer)
        # pushed along the inner's normals, where the inner folds (the armpit) the outer can meet the body again,
        # and pushed out of the body it can go behind the inner: the last pass has both as one collider
        both = np.concatenate([body, inner])
        outer = self.last.refine_frame(outer, both, self.both_surface, r)
        if stages is not None:
            stages.append(outer)
        if report is None:
            return inner, outer
        b, bn, bt, i, ln = self.both_surface.parts(both)
        report.inner_in_body_before.append(r.inside_before[0])
        report.inner_in_body_after.append(r.inside_after[0])
        report.outer_in_body_before.append(r.inside_before[1])
        report.outer_in_body_after.append(int(np.count_nonzero(self.body_surface.query(b, bn, outer, bt)[0] < 0)))
        report.outer_in_inner_before.append(r.inside_before[2])
        report.outer_in_inner_after.append(
            int(np.count_nonzero(self.both_surface.layer.query(i, ln, outer)[0] < 0)))
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
