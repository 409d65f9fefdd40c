"""Collision refinement (Wang et al. 2019, Sec. 3.5): push garment vertices out of the body
while keeping the garment's local shape.

Per frame, with V the input garment and C the vertices inside the body, solve

    min_{V*}  ||L (V* - V)||^2 + mu ||V* - V||^2 + w sum_{i in C} ||v*_i - (p_i + eps n_i)||^2

where L is the uniform Laplacian of the template (fixed per garment), p_i and n_i the
closest point on the body's triangles and its normal. mu keeps the change local: the
displacement dies out within a ring or two of C, so each iteration solves only on C grown by
`rings` rings (the rest is held: the "affected region" solve). mu = 0.5 and 2 rings were
chosen by bench/refine.py: against mu = 0.02 and 3 rings they leave fewer vertices inside,
run faster and stretch edges less (a wide smooth field drags outside cloth along with
targets on opposite sides of a limb). Iterate until no vertex is inside (a few
iterations); a vertex that was outside in the input and that the smooth solve dragged inside
is aimed back at its input position, not at a closest point that may lie across a limb.

Progressive pass: inside vertices are visited in order of graph (geodesic) distance from
vertices known to be outside; each is placed at its placed neighbours' mean plus its own
offset from them and, if that is inside, at the closest body point to it, so deep vertices
come out on their neighbours' side, not through the far side of a limb. It is used (a) at
the start, per connected inside patch, when the patch's closest-point targets would stretch
an edge by more than `tear` and the progressive targets stretch it less (a limb through the
cloth, whose closest points fall on both sides of it), and (b) for frames the fast path
does not converge on; there, cloth that was outside in the input is aimed back at its input
position, as in the fast path, rather than placed after its neighbours across the limb.

Stretch relief: closest-point targets on both sides of a crease (between the thighs, at the
armpit) or of a limb stretch the edges between them, and the smooth solve spreads the stretch
only a ring or two. With `relief_iterations` > 0 (RELIEF_ITERATIONS = 10 by default; 0 turns it
off; its cost in docs/refine.md), edges elongated by more than `relief_threshold` against the input
are then relaxed: on those edges' vertices grown by `rings` rings, a few Jacobi rounds of position-based
edge-length projection (each stretched edge shortened back towards its input length, nothing
compressed; vertices outside the region held), each round followed by pushing whatever went
inside back out: onto its closest body point + eps every `relief_query_every` rounds and in the
last, onto its last closest point's tangent plane in between. The stretched cloth slides along the body towards
the crease instead of spanning it, and cloth the body's own overlap hides from the sign test is
pulled out by its pushed neighbours. A connected patch whose largest stretch the pass would raise (pulled round
a limb to its far side) keeps its refined position: the pass never raises a patch's largest stretch.

Shapes: garment (T, N, 3) m; faces (F, 3); body (T, M, 3) m; body_faces (G, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from drape.geometry.mesh import (
    adjacency_matrix,
    uniform_laplacian,
    unique_edges,
    vertex_face_incidence,
    vertex_normals,
)
from drape.geometry.nearest import VertexTree
from drape.geometry.queries import closest_point_on_triangles

# the defaults of refine(), Refiner and the service's refine options (drape.schemas.outfits.RefineOptions)
EPS = 0.003  # metres kept from the body surface
MAX_ITERATIONS = 3  # fast-path iterations before the progressive pass
RELIEF_ITERATIONS = 10  # rounds of the stretch relief pass (0: none)
STRETCH_RATIO = 1.5  # with a rest shape: the edge-limit pass's cap, times the rest length
STRETCH_ITERATIONS = 15  # rounds of the edge-limit pass
VERIFY_K = 8  # nearest body vertices whose faces the last check looks at (0: no check)
VERIFY_ROUNDS = 4  # rounds of the last check's projection
VERIFY_WITHIN = 0.01  # metres: vertices the refinement's own query finds closer than this are checked
FAR_K = 5  # body surfaces: a point read outside that one of this many nearest vertices reads inside is read again
SNAP_MARGIN = 0.25  # the third round's second try: eps x this from the body (0.75 mm)
STRETCH_EXTRA = 15  # edge-limit rounds the pass may add near a new edge over SNAP_STRETCH x rest that shrinks
STRETCH_EXTRA_PACE = 2.0  # fast enough: under that within those rounds at this many times its last block's pace
STRETCH_EXTRA_OMEGA = 1.5  # those rounds' step (the main rounds': stretch_omega)
SNAP_STRETCH = 2.0  # the last check's third round: no edge longer than this x the vertex's longest in the input


def body_tree(body: np.ndarray) -> VertexTree:
    """KD-tree over one posed body's vertices (M, 3), rebuilt every frame (drape.geometry.nearest)."""
    return VertexTree(body)


class Collider(Protocol):
    """What the refinement pushes a garment out of: the body (`BodySurface`), another garment layer
    (drape.geometry.layers). `normals(body)` is called once per frame, before any `query` on the same array."""

    def normals(self, body: np.ndarray) -> np.ndarray: ...

    def query(self, body: np.ndarray, normals: np.ndarray, points: np.ndarray,
              tree: VertexTree | None = None, k: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


class BodySurface:
    """Closest points on one posed body: candidates are the faces around the k nearest body vertices.

    far_k: a point read outside (far: by the normals of its k nearest; close: by the faces around them) that the
    normal of one of its far_k nearest vertices reads inside is asked again over the faces around its far_k nearest
    (None: not). The refinement's surfaces use FAR_K (docs/refine.md); the served rig's collision fit
    (drape.runtime.collision_fit) keeps None, as its model was chosen with.

    body_faces' vertex->face incidence is built once per topology and reused for every frame.
    """

    def __init__(self, body_faces: np.ndarray, num_vertices: int, k: int = 2, far: float = 0.015,
                 far_k: int | None = None):
        self.faces = np.asarray(body_faces, dtype=np.int64)
        self.k, self.far, self.far_k = k, far, far_k
        inc = vertex_face_incidence(self.faces, num_vertices)
        deg = np.diff(inc.indptr)
        self.fmax = int(deg.max())
        table = np.full((num_vertices, self.fmax), len(self.faces), dtype=np.int64)  # padded past the last face
        slot = np.arange(inc.nnz) - np.repeat(inc.indptr[:-1], deg)
        table[np.repeat(np.arange(num_vertices), deg), slot] = inc.indices
        self.vertex_faces = table  # (M, fmax)
        self.in_face = deg > 0  # (M,) a registered body may carry vertices no face uses
        self.incidence = inc  # (M, G) vertex-face incidence, kept for the per-frame normals

    def normals(self, body: np.ndarray) -> np.ndarray:
        """Unit vertex normals of one posed body (M, 3) -> (M, 3)."""
        return vertex_normals(body, self.faces, self.incidence)

    def query(self, body: np.ndarray, normals: np.ndarray, points: np.ndarray,
              tree: VertexTree | None = None, k: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """points (P, 3) -> (signed distance (P,), closest point (P, 3), unit normal there (P, 3)).

        Points farther than `far` from every body vertex and on the outer side of the normals of
        all k nearest ones are outside: they keep the nearest vertex as their closest point. The
        others get the exact closest point on the faces around their k nearest body vertices
        (k: this surface's `k` unless given).
        """
        return self._query(body, normals, points, tree, k)[:3]

    def _query(self, body: np.ndarray, normals: np.ndarray, points: np.ndarray, tree: VertexTree | None,
               k: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """`query`'s answer and each point's nearest body vertex (P,) int."""
        if len(points) == 0:
            return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
        tree = tree if tree is not None else body_tree(body)
        k = k or self.k
        # points are asked again over far_k nearest: one KD search serves both readings
        kk = max(k, self.far_k or 0)
        dist, near = tree.query(points, k=kk)
        # `take` rather than fancy indexing: it gathers rows several times faster
        around, around_n = body.take(near, axis=0), normals.take(near, axis=0)  # (P, kk, 3)
        cp, n = around[:, 0].copy(), around_n[:, 0].copy()
        sd = dist[:, 0].copy()
        # inner side of any of the nearest: where the body overlaps itself (armpit, thighs) the nearest
        # vertex can belong to the part the point is not inside
        inner = np.einsum("pkc,pkc->pk", points[:, None] - around, around_n) < 0
        # a nearest vertex in no face has no normal to tell the side by
        close = (dist[:, 0] < self.far) | inner[:, :k].any(axis=1) | ~self.in_face.take(near[:, 0])
        idx = np.nonzero(close)[0]
        if len(idx):
            sd[idx], cp[idx], n[idx] = self._closest_on_faces(body, normals, points[idx], near[idx, :k])
        if kk > k:
            # a point read outside (by its k nearest normals when far, by the faces around its k nearest when close)
            # that one of its far_k nearest vertices' normals reads inside is asked again over the faces around its
            # far_k nearest: where the body folds (the armpit) the k nearest and their faces can all face it from
            # outside while it is inside the limb (a far point all far_k nearest read outside keeps the nearest
            # vertex, its distance and normal)
            ask = np.nonzero(inner.any(axis=1) & (sd >= 0))[0]
            if len(ask):
                sd[ask], cp[ask], n[ask] = self._closest_on_faces(body, normals, points[ask], near[ask])
        return sd, cp, n, near[:, 0]

    def _closest_on_faces(self, body: np.ndarray, normals: np.ndarray, points: np.ndarray,
                          around: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """points (P, 3), around (P, K) body vertex indices -> (signed distance (P,), closest point (P, 3), unit
        normal there (P, 3)): the exact closest point on the faces around each point's K body vertices, its side by
        the normal interpolated there."""
        k = around.shape[1]
        lost = np.nonzero(~self.in_face.take(around).any(axis=1))[0]
        if len(lost):  # its body vertices are in no face: take the k nearest that are
            used = np.nonzero(self.in_face)[0]
            kk = min(k, len(used))
            q = cKDTree(body[used]).query(points[lost], k=kk)[1].reshape(len(lost), kk)
            around = around.copy()
            around[lost] = used[q[:, np.arange(k) % kk]]
        # the faces around the body vertices, each face once per point
        cand = np.sort(self.vertex_faces.take(around, axis=0).reshape(len(points), -1), axis=1)
        keep = cand < len(self.faces)
        keep[:, 1:] &= cand[:, 1:] != cand[:, :-1]
        row, face = np.nonzero(keep)[0], cand[keep]  # row-major: each point's candidates are contiguous
        f = self.faces.take(face, axis=0)
        # each corner (candidates, 3) contiguous: the closest-point test runs several times faster than on views
        corners = [body.take(f[:, i], axis=0) for i in range(3)]
        pts = points.take(row, axis=0)
        c, bary = closest_point_on_triangles(pts, *corners)
        d2 = np.einsum("pc,pc->p", pts - c, pts - c)
        start = np.searchsorted(row, np.arange(len(points)))
        # the first candidate of each point reaching that point's smallest distance
        at_min = d2 == np.repeat(np.minimum.reduceat(d2, start), np.diff(np.append(start, len(row))))
        first = np.nonzero(at_min)[0]
        best = first[np.searchsorted(row[first], np.arange(len(points)))]
        c, bary, fb = c[best], bary[best], f[best]
        nn = np.einsum("pk,pkc->pc", bary, normals.take(fb, axis=0))
        nn /= np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), 1e-12)
        diff = points - c
        d = np.linalg.norm(diff, axis=1)
        return np.where(np.einsum("pc,pc->p", diff, nn) < 0, -d, d), c, nn


@dataclass
class RefineReport:
    """Per frame: vertices inside before/after, iterations, max displacement (m), progressive pass used."""

    inside_before: list[int] = field(default_factory=list)
    inside_after: list[int] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    max_displacement: list[float] = field(default_factory=list)
    progressive: list[bool] = field(default_factory=list)
    relieved: list[int] = field(default_factory=list)  # vertices the stretch relief pass worked on
    verified: list[int] = field(default_factory=list)  # vertices the last check found inside and put out


class Refiner:
    """Refinement for one garment topology; the Laplacian and its square are built once."""

    def __init__(self, faces: np.ndarray, num_vertices: int, eps: float = EPS, weight: float = 1e3,
                 mu: float = 0.5, rings: int = 2, max_iterations: int = MAX_ITERATIONS, tear: float | None = 0.02,
                 relief_threshold: float = 0.005, relief_iterations: int = RELIEF_ITERATIONS,
                 relief_query_every: int = 5, rest: np.ndarray | None = None, stretch_ratio: float = STRETCH_RATIO,
                 stretch_iterations: int = STRETCH_ITERATIONS, stretch_query_every: int = 5, stretch_omega: float = 1.5,
                 stretch_extra: int = STRETCH_EXTRA, stretch_extra_omega: float = STRETCH_EXTRA_OMEGA,
                 verify_k: int = VERIFY_K, verify_within: float = VERIFY_WITHIN,
                 verify_stretch: float = np.inf, rest_length: np.ndarray | None = None):
        self.faces = np.asarray(faces, dtype=np.int64)
        self.n = num_vertices
        self.eps, self.weight, self.mu, self.rings, self.max_iterations = eps, weight, mu, rings, max_iterations
        self.tear = tear
        self.relief_threshold, self.relief_iterations = relief_threshold, relief_iterations
        self.relief_query_every = relief_query_every
        self.stretch_ratio, self.stretch_iterations = stretch_ratio, stretch_iterations
        self.stretch_query_every, self.stretch_omega = stretch_query_every, stretch_omega
        # edge-limit rounds beyond stretch_iterations, only near a new long edge that shrinks
        self.stretch_extra = stretch_extra
        self.stretch_extra_omega = stretch_extra_omega  # those rounds' step
        self.verify_k, self.verify_within, self.verify_stretch = verify_k, verify_within, verify_stretch
        lap = uniform_laplacian(self.faces, num_vertices)
        self.system = (lap.T @ lap + mu * sp.identity(num_vertices)).tocsr()  # L^T L + mu I, fixed
        self.adjacency = adjacency_matrix(self.faces, num_vertices).tocsr()
        self.edges = unique_edges(self.faces)  # (E, 2)
        self.rest_length = None  # (E,) the template's edge lengths, m, when `rest` or `rest_length` is given
        if rest is not None and rest_length is not None:
            raise ValueError("give rest or rest_length, not both")
        if rest is not None:
            r = np.asarray(rest, dtype=np.float64)
            if r.shape != (num_vertices, 3):
                raise ValueError(f"rest must be ({num_vertices}, 3), got {r.shape}")
            self.rest_length = np.linalg.norm(r[self.edges[:, 0]] - r[self.edges[:, 1]], axis=1)
        elif rest_length is not None:  # (E,) m, in the order of unique_edges(faces)
            self.rest_length = np.asarray(rest_length, dtype=np.float64)
            if self.rest_length.shape != (len(self.edges),):
                raise ValueError(f"rest_length must be ({len(self.edges)},), got {self.rest_length.shape}")
        if self.rest_length is not None:
            a, b = self.edges[:, 0], self.edges[:, 1]
            # (N, N) each edge's rest length at both of its ends, for the last check
            self.rest_pairs = sp.csr_matrix((np.concatenate([self.rest_length, self.rest_length]),
                                             (np.concatenate([a, b]), np.concatenate([b, a]))),
                                            shape=(num_vertices, num_vertices))

    def _patch_stretch(self, v: np.ndarray, inside: np.ndarray, targets: np.ndarray,
                       patch: np.ndarray, num_patches: int) -> np.ndarray:
        """Largest edge elongation (m) per inside patch if `inside` moved straight to `targets`.

        patch: (N,) index of the connected inside patch of each vertex (-1 outside) -> (num_patches,).
        """
        moved = v.copy()
        moved[inside] = targets
        owner = np.maximum(patch[self.edges[:, 0]], patch[self.edges[:, 1]])  # an edge touches <= 1 patch
        touched = owner >= 0
        a, b = self.edges[touched, 0], self.edges[touched, 1]
        grow = np.linalg.norm(moved[a] - moved[b], axis=1) - np.linalg.norm(v[a] - v[b], axis=1)
        worst = np.full(num_patches, -np.inf)
        np.maximum.at(worst, owner[touched], grow)
        return worst

    def _region(self, seeds: np.ndarray) -> np.ndarray:
        mask = np.zeros(self.n, dtype=bool)
        mask[seeds] = True
        for _ in range(self.rings):
            mask |= (self.adjacency @ mask.astype(np.float32)) > 0
        return np.nonzero(mask)[0]

    def _solve(self, v: np.ndarray, inside: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One step: the displacement on the affected region (returned too), zero outside it."""
        region = self._region(inside)
        a = self.system[region][:, region].tocsc()
        local = np.searchsorted(region, inside)
        a = a + sp.csc_matrix((np.full(len(inside), self.weight), (local, local)), shape=a.shape)
        rhs = np.zeros((len(region), 3))
        rhs[local] = self.weight * (targets - v[inside])
        out = v.copy()
        out[region] += splu(a).solve(rhs)
        return out, region

    def _progressive_targets(self, v: np.ndarray, sd: np.ndarray, surface: Collider, body: np.ndarray,
                             normals: np.ndarray, tree: VertexTree,
                             only: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Targets for inside vertices (those in the (N,) mask `only`, if given), placed front by
        front in order of graph distance from outside ones -> (vertex indices, (K, 3) targets).

        Works on the subgraph of those vertices and their (outside) neighbours only.
        """
        todo = sd < 0 if only is None else (sd < 0) & only
        ring = todo | ((self.adjacency @ todo.astype(np.float32)) > 0)
        idx = np.nonzero(ring)[0]  # the vertices to place and their (outside) neighbours
        adj = self.adjacency[idx][:, idx].tocsr()
        rest, placed = v[idx], v[idx].copy()
        done = ~todo[idx]
        visited = []
        while not done.all():
            front = np.nonzero(~done & ((adj @ done.astype(np.float32)) > 0))[0]
            if len(front) == 0:  # a component with no outside vertex: aim at its own closest points
                front = np.nonzero(~done)[0]
                anchors = placed[front]
            else:
                w = adj[front].multiply(done[None, :].astype(np.float32)).tocsr()
                wsum = np.maximum(np.asarray(w.sum(axis=1)), 1.0)
                # the placed neighbours' mean plus the vertex's own offset from them: local shape kept
                anchors = (w @ placed) / wsum + (rest[front] - (w @ rest) / wsum)
            # aim at the body point closest to that: the placed neighbours' side of the body
            sd_a, cp, n = surface.query(body, normals, anchors, tree)
            placed[front] = np.where((sd_a >= self.eps)[:, None], anchors, cp + self.eps * n)
            done[front] = True
            visited.append(front)
        order = np.concatenate(visited) if visited else np.zeros(0, dtype=np.int64)
        return idx[order], placed[order]

    def _untorn_targets(self, v: np.ndarray, inside: np.ndarray, direct: np.ndarray, sd: np.ndarray,
                        surface: Collider, body: np.ndarray, normals: np.ndarray,
                        tree: VertexTree) -> np.ndarray | None:
        """Targets (K, 3) for `inside` with front-by-front placement where it tears less, or None.

        Closest points (`direct`) on opposite sides of a limb tear the cloth; placing front by
        front from the outside may tear less. Per connected inside patch whose direct targets
        stretch an edge by more than `tear`, take the targets that stretch less. None when no
        patch is better off (the caller keeps the direct targets).
        """
        num, label = connected_components(self.adjacency[inside][:, inside], directed=False)
        patch = np.full(self.n, -1)
        patch[inside] = label
        worst = self._patch_stretch(v, inside, direct, patch, num)
        tearing = worst > self.tear
        if not tearing.any():
            return None
        only = np.zeros(self.n, dtype=bool)
        only[inside[tearing[label]]] = True
        ordered, placed = self._progressive_targets(v, sd, surface, body, normals, tree, only)
        better = (self._patch_stretch(v, ordered, placed, patch, num) < worst) & tearing
        if not better.any():
            return None
        targets = v.copy()
        targets[inside] = direct
        use = better[patch[ordered]]
        targets[ordered[use]] = placed[use]
        return targets[inside]

    def _hold_outside(self, xm: np.ndarray, cp: np.ndarray, nn: np.ndarray, query: bool, surface: Collider,
                      body: np.ndarray, normals: np.ndarray, tree: VertexTree,
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One round's collision step of the relief and edge-limit passes, on moved points xm (P, 3), in place:
        with `query`, what is inside goes to its closest body point + eps (cp, nn: renewed); otherwise onto the
        outer side of its last closest point's tangent plane (cp (P, 3), nn (P, 3): those points and normals).
        -> (signed distances (P,), eps where put out; cp; nn; inside (P,) bool)."""
        if query:
            s, cp, nn = surface.query(body, normals, xm, tree)
            inside = s < 0
            xm[inside] = cp[inside] + self.eps * nn[inside]
        else:
            s = np.einsum("pc,pc->p", xm - cp, nn)
            inside = s < 0
            xm[inside] += (self.eps - s[inside])[:, None] * nn[inside]
        s[inside] = self.eps
        return s, cp, nn, inside

    def _settle(self, xm: np.ndarray, s: np.ndarray, inside: np.ndarray, refined: np.ndarray,
                refined_sd: np.ndarray, surface: Collider, body: np.ndarray, normals: np.ndarray,
                tree: VertexTree) -> None:
        """After the last round, in place on xm (P, 3) and s (P,): a point placed off one part's surface can land
        inside another (the armpit, between the thighs), so what was just put out (`inside`) is put out once
        more; what is still inside goes back to `refined` (P, 3) with its distance `refined_sd` (P,)."""
        check = np.nonzero(inside)[0]
        q, c, cn = surface.query(body, normals, xm[check], tree)
        s[check] = q
        check, c, cn = check[q < 0], c[q < 0], cn[q < 0]
        xm[check] = c + self.eps * cn
        q = surface.query(body, normals, xm[check], tree)[0]
        back = check[q < 0]
        xm[back] = refined[back]
        s[back] = refined_sd[back]
        s[check[q >= 0]] = q[q >= 0]

    def _relieve(self, v0: np.ndarray, v: np.ndarray, sd: np.ndarray, closest: np.ndarray,
                 closest_normal: np.ndarray, surface: Collider, body: np.ndarray, normals: np.ndarray,
                 tree: VertexTree) -> tuple[np.ndarray, int]:
        """Stretch relief: v0, v (N, 3) input and refined garment -> (relieved garment (N, 3), vertices worked on).

        sd (N,), closest (N, 3), closest_normal (N, 3): v's signed distances, closest body points and
        their normals; sd is updated in place for the vertices that moved.
        """
        e0, e1 = self.edges[:, 0], self.edges[:, 1]
        moved = np.any(v != v0, axis=1)
        near = np.nonzero(moved[e0] | moved[e1])[0]  # only edges the refinement moved can be stretched
        if self.relief_iterations == 0 or len(near) == 0:
            return v, 0
        i0, i1 = e0[near], e1[near]
        stretched = np.linalg.norm(v[i0] - v[i1], axis=1) - np.linalg.norm(v0[i0] - v0[i1], axis=1)
        stretched = near[stretched > self.relief_threshold]
        if len(stretched) == 0:
            return v, 0
        free = np.zeros(self.n, dtype=bool)
        free[e0[stretched]] = free[e1[stretched]] = True
        for _ in range(self.rings):
            free |= (self.adjacency @ free.astype(np.float32)) > 0
        touching = free[e0] | free[e1]  # edges to held vertices pull too
        ea, eb = e0[touching], e1[touching]
        length = np.linalg.norm(v0[ea] - v0[eb], axis=1)  # the input's edge lengths, m
        verts = np.unique(np.concatenate([ea, eb]))
        a, b = np.searchsorted(verts, ea), np.searchsorted(verts, eb)
        m = len(verts)
        moving = np.nonzero(free[verts])[0]
        x = v[verts].copy()
        cp, nn = closest[verts[moving]], closest_normal[verts[moving]]
        for k in range(self.relief_iterations):
            d = x[a] - x[b]
            dl = np.sqrt(np.einsum("ec,ec->e", d, d))
            excess = np.maximum(dl - length, 0.0)
            pull = (excess / np.maximum(dl, 1e-12))[:, None] * d  # a -> b by the excess
            on = (excess > 0).astype(np.float64)
            count = np.maximum(np.bincount(a, on, m) + np.bincount(b, on, m), 1.0)
            # each end moves by its stretched edges' mean excess (twice the textbook half step: converges faster)
            force = np.stack([np.bincount(a, pull[:, c], m) - np.bincount(b, pull[:, c], m) for c in range(3)], axis=1)
            xm = x[moving] - force[moving] / count[moving, None]
            query = (k + 1) % self.relief_query_every == 0 or k == self.relief_iterations - 1
            s, cp, nn, inside = self._hold_outside(xm, cp, nn, query, surface, body, normals, tree)
            x[moving] = xm
        xm = x[moving]
        self._settle(xm, s, inside, v[verts[moving]], sd[verts[moving]], surface, body, normals, tree)
        x[moving] = xm
        # the pass may only lower a connected patch's largest stretch: a patch it made worse (pulled round
        # a limb to its far side) keeps its refined position
        mov = free[verts]  # (m,) the moving vertices as a mask
        inner = mov[a] & mov[b]
        num, label = connected_components(sp.csr_matrix((np.ones(np.count_nonzero(inner)), (a[inner], b[inner])),
                                                        shape=(m, m)), directed=False)
        patch = label[np.where(mov[a], a, b)]  # (edges,) the patch of each edge's moving end
        x0 = v[verts]
        worst_before, worst_after = np.full(num, -np.inf), np.full(num, -np.inf)
        np.maximum.at(worst_before, patch, np.linalg.norm(x0[a] - x0[b], axis=1) - length)
        np.maximum.at(worst_after, patch, np.linalg.norm(x[a] - x[b], axis=1) - length)
        worse = (worst_after > worst_before)[label[moving]]
        x[moving[worse]] = x0[moving[worse]]
        s[worse] = sd[verts[moving[worse]]]
        out = v.copy()
        out[verts[moving]] = x[moving]
        sd[verts[moving]] = s
        return out, int(np.count_nonzero(~worse))

    def _limit_stretch(self, v0: np.ndarray, v: np.ndarray, sd: np.ndarray, closest: np.ndarray,
                       closest_normal: np.ndarray, surface: Collider, body: np.ndarray, normals: np.ndarray,
                       tree: VertexTree) -> tuple[np.ndarray, int]:
        """Edge-length limits solved together with the collisions (needs `rest`): v0, v (N, 3) input and
        refined garment -> (garment (N, 3), vertices worked on).

        Each edge's cap is max(stretch_ratio x its rest length, its input length): an edge the input already
        stretched past the ratio is not made longer, and one the input compressed (a fold) may unfold. On the
        vertices of the edges over their cap grown by `rings` rings, `stretch_iterations` Jacobi rounds (then up
        to `stretch_extra` more on a smaller region, below):
        every edge over its cap is shortened to it (a held end takes no share; each vertex's corrections
        averaged and scaled by `stretch_omega`), then whatever went inside is put back out, as in the relief
        pass (its last closest point's tangent plane; closest point + eps every `stretch_query_every`
        rounds and in the last). The collisions win at the end: a vertex still inside after two more
        projections goes back to its refined position; then the moved ends of any edge the pass left over
        SNAP_STRETCH x its rest length, that was not so before it nor in the input, go back to theirs too.
        Extra rounds (`stretch_extra`, STRETCH_EXTRA by default; docs/refine.md): an edge the input had under
        SNAP_STRETCH x rest that is over it after the rounds, and shrank over their last block of
        `stretch_query_every` fast enough to be under it within `stretch_extra` rounds at STRETCH_EXTRA_PACE x that
        pace, gets more rounds on its vertices grown by `rings` rings (the rest held), block by block while one such
        edge keeps that pace. An edge that does not shrink is held apart by the body (a limb through the cloth,
        which no edge length takes out) and costs no more rounds.
        sd, closest, closest_normal: as in `_relieve` (sd updated in place).
        """
        assert self.rest_length is not None, "the edge-limit pass needs the rest shape"
        rest_length = self.rest_length
        e0, e1 = self.edges[:, 0], self.edges[:, 1]

        def given(edges: np.ndarray) -> np.ndarray:  # the input's lengths of these edges
            return np.linalg.norm(v0[e0[edges]] - v0[e1[edges]], axis=1)

        def cap_of(edges: np.ndarray, length0: np.ndarray) -> np.ndarray:  # stretch_ratio x rest, or the input's
            return np.maximum(self.stretch_ratio * rest_length[edges], length0)

        # an edge neither of whose ends the refinement moved keeps its input length: never over its cap
        moved = np.any(v != v0, axis=1)
        near = np.nonzero(moved[e0] | moved[e1])[0]
        over = near[np.linalg.norm(v[e0[near]] - v[e1[near]], axis=1) > cap_of(near, given(near)) * (1 + 1e-6)]
        if self.stretch_iterations == 0 or len(over) == 0:
            return v, 0
        free = np.zeros(self.n, dtype=bool)
        free[e0[over]] = free[e1[over]] = True
        for _ in range(self.rings):
            free |= (self.adjacency @ free.astype(np.float32)) > 0
        touching = np.nonzero(free[e0] | free[e1])[0]  # edges to held vertices pull too
        ea, eb, length0 = e0[touching], e1[touching], given(touching)
        cap = cap_of(touching, length0)
        verts = np.unique(np.concatenate([ea, eb]))
        a, b = np.searchsorted(verts, ea), np.searchsorted(verts, eb)
        m, k = len(verts), len(ea)
        moving = np.nonzero(free[verts])[0]
        fa, fb = free[ea].astype(np.float64), free[eb].astype(np.float64)
        wa, wb = fa / (fa + fb), fb / (fa + fb)  # shares of an edge's correction; a held end takes none
        rows, cols = np.concatenate([a, b]), np.tile(np.arange(k), 2)
        # (moving, edges): each moving vertex's signed shares of its edges' corrections, and its edge count
        share = sp.csr_matrix((np.concatenate([-wa, wb]), (rows, cols)), shape=(m, k))[moving]
        incident = sp.csr_matrix((np.ones(2 * k), (rows, cols)), shape=(m, k))[moving]
        x = v[verts].copy()
        xm = x[moving]
        cp, nn = closest[verts[moving]], closest_normal[verts[moving]]
        limit = SNAP_STRETCH * rest_length[touching]
        grown = length0 <= limit  # edges the input had under SNAP_STRETCH x rest
        q = self.stretch_query_every

        def jacobi(pos: np.ndarray, at: np.ndarray, ea: np.ndarray, eb: np.ndarray, edge_cap: np.ndarray,
                   inc: sp.spmatrix | np.ndarray, shr: sp.spmatrix | np.ndarray,
                   omega: float) -> tuple[np.ndarray, np.ndarray]:
            """One Jacobi round on the moving points pos (P, 3), at `at` in x, over the edges (ea, eb) with their
            caps; inc, shr (P, E): incidence and signed shares -> (moved points, the edges' lengths before)."""
            x[at] = pos
            d = x[ea] - x[eb]
            dl = np.sqrt(np.einsum("ec,ec->e", d, d))
            excess = np.maximum(dl - edge_cap, 0.0)
            corr = (excess / np.maximum(dl, 1e-12))[:, None] * d  # a -> b by the excess
            count = np.maximum(inc @ (excess > 0).astype(np.float64), 1.0)
            return pos + (omega / count)[:, None] * (shr @ corr), dl

        before = np.zeros(k)  # the edges' lengths a block of q rounds back (for stretch_extra)
        for it in range(self.stretch_iterations):
            xm, dl = jacobi(xm, moving, a, b, cap, incident, share, self.stretch_omega)
            if it == self.stretch_iterations - q:
                before = dl
            query = (it + 1) % q == 0 or it == self.stretch_iterations - 1
            s, cp, nn, inside = self._hold_outside(xm, cp, nn, query, surface, body, normals, tree)
        if self.stretch_extra and self.stretch_iterations >= q:
            # stretch_extra (docstring): rounds as above, a query every q and in the last, on the watched edges'
            # vertices grown by `rings` rings
            x[moving] = xm
            now = np.linalg.norm(x[a] - x[b], axis=1)
            blocks = self.stretch_extra / q
            shrinking = grown & (now > limit) & (now - limit <= STRETCH_EXTRA_PACE * blocks * (before - now))
            if np.any(shrinking):
                region = np.zeros(self.n, dtype=bool)
                region[verts[a[shrinking]]] = region[verts[b[shrinking]]] = True
                for _ in range(self.rings):
                    region |= (self.adjacency @ region.astype(np.float32)) > 0
                sub = np.nonzero(region[verts[moving]])[0]  # positions in xm
                sub_incident = incident[sub]
                sub_edges = np.unique(sub_incident.indices)
                # a few hundred vertices and edges at most: dense products are cheaper than sparse ones here
                sub_share, sub_incident = share[sub][:, sub_edges].toarray(), sub_incident[:, sub_edges].toarray()
                at = moving[sub]
                sa, sb, sub_cap, sub_limit = a[sub_edges], b[sub_edges], cap[sub_edges], limit[sub_edges]
                watched, last = shrinking[sub_edges], now[sub_edges]
                xs, cps, nns = xm[sub], cp[sub], nn[sub]
                for r in range(self.stretch_extra):
                    moved, dl = jacobi(xs, at, sa, sb, sub_cap, sub_incident, sub_share, self.stretch_extra_omega)
                    if r % q == 0 and r > 0:  # a block ended: go on while a watched edge keeps the pace
                        left = (self.stretch_extra - r) / q
                        watched &= (dl > sub_limit) & (dl - sub_limit <= STRETCH_EXTRA_PACE * left * (last - dl))
                        if not np.any(watched):
                            break
                        last = dl
                    xs = moved
                    query = (r + 1) % q == 0 or r == self.stretch_extra - 1
                    ss, cps, nns, ins = self._hold_outside(xs, cps, nns, query, surface, body, normals, tree)
                xm[sub], cp[sub], nn[sub], s[sub], inside[sub] = xs, cps, nns, ss, ins
        self._settle(xm, s, inside, v[verts[moving]], sd[verts[moving]], surface, body, normals, tree)
        # the pass leaves no edge over SNAP_STRETCH x its rest length that was not so before it nor in the input (a
        # vertex the settle sent back to its refined place, or one put out sideways, beside a neighbour the rounds
        # moved): the moved ends of such edges go back to their refined places until none is left
        x[moving] = xm
        x0 = v[verts]
        fine = (np.linalg.norm(x0[a] - x0[b], axis=1) <= limit) & grown
        slot = np.full(m, -1)
        slot[moving] = np.arange(len(moving))
        while True:
            bad = fine & (np.linalg.norm(x[a] - x[b], axis=1) > limit)
            ends = np.unique(np.concatenate([a[bad], b[bad]]))
            ends = ends[(slot[ends] >= 0) & np.any(x[ends] != x0[ends], axis=1)]
            if len(ends) == 0:  # (a bad edge has a moved end: with both at their refined places it was fine)
                break
            x[ends] = x0[ends]
            s[slot[ends]] = sd[verts[ends]]
        xm = x[moving]
        out = v.copy()
        out[verts[moving]] = xm
        sd[verts[moving]] = s
        return out, len(moving)

    def _put_out(self, x: np.ndarray, surface: Collider, body: np.ndarray, normals: np.ndarray,
                 tree: VertexTree, margin: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Points x (P, 3) -> (placed (P, 3), signed distance (P,) there, by the `verify_k` query).

        Each inside point goes to its closest point + eps (times `margin`); one that lands inside another part
        (a crease) moves along the bisector of the two parts' normals until it is that far outside both tangent
        planes, for up to VERIFY_ROUNDS rounds."""
        eps = self.eps * margin
        out = x.copy()
        sd, c, nn = surface.query(body, normals, out, tree, k=self.verify_k)
        todo = np.nonzero(sd < 0)[0]
        c, nn = c[todo], nn[todo]
        out[todo] = c + eps * nn
        for _ in range(VERIFY_ROUNDS):
            if len(todo) == 0:
                break
            q, c2, n2 = surface.query(body, normals, out[todo], tree, k=self.verify_k)
            sd[todo] = q
            keep = q < 0
            todo, p, c, nn, c2, n2 = todo[keep], out[todo[keep]], c[keep], nn[keep], c2[keep], n2[keep]
            d = nn + n2
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
            need = [(eps - np.einsum("pc,pc->p", p - ci, ni)) / np.maximum(np.einsum("pc,pc->p", d, ni), 0.1)
                    for ci, ni in ((c, nn), (c2, n2))]
            out[todo] = p + np.maximum(np.maximum(need[0], need[1]), 0.0)[:, None] * d
            c, nn = c2, n2
        if len(todo):  # the last round's moves, not checked: count them as inside
            sd[todo] = np.minimum(sd[todo], -1e-9)
        return out, sd

    def _verify(self, v0: np.ndarray, v: np.ndarray, sd: np.ndarray, surface: Collider, body: np.ndarray,
                normals: np.ndarray, tree: VertexTree) -> tuple[np.ndarray, int]:
        """The last check: v0, v (N, 3) input and refined garment -> (garment (N, 3), vertices it put out).

        Where the body overlaps itself (the armpit, the thighs) the faces around a point's `surface.k` nearest
        body vertices can all belong to the part it is not inside, and the point reads as outside. The
        vertices the refinement's query found within `verify_within` of the body (sd (N,), updated in place)
        are queried again over the faces around their `verify_k` nearest body vertices. Each one inside is
        put out (`_put_out`) from two starts: where it is, and its neighbours' mean plus its own offset from
        them in the input (their side of the body: straight out of an arm can be its far side). Of the two,
        the one outside whose longest edge to its neighbours is shorter is the target of one smooth step of
        the refinement (`_solve`: the neighbours come along); twice. The smooth step can fall a few mm short of
        its targets; a third round puts what is still inside straight at its place, where no edge to its
        neighbours becomes longer than SNAP_STRETCH x the longest in the input (with a rest shape, nor any edge over
        SNAP_STRETCH x its rest length that the input did not have that long), trying SNAP_MARGIN x eps where eps
        finds no such place. What is still inside counts as inside in the report.
        """
        if not self.verify_k:
            return v, 0
        put = 0
        near = np.nonzero(sd < self.verify_within)[0]
        sd[near] = surface.query(body, normals, v[near], tree, k=self.verify_k)[0]
        stuck = False  # a smooth round found no place: the next smooth one would not either
        for last in (False, False, True):
            # every vertex within reach now has this check's reading: what moved was queried again below
            bad = np.nonzero(sd < 0)[0]
            if len(bad) == 0:
                break
            if stuck and not last:
                continue
            adj = self.adjacency[bad]  # (B, N) the bad vertices' neighbours
            deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)[:, None]
            anchored = (adj @ v) / deg + v0[bad] - (adj @ v0) / deg
            if self.rest_length is None:
                rows, cols = adj.nonzero()
            else:
                pairs = self.rest_pairs[bad].tocoo()
                rows, cols = pairs.row, pairs.col
            given = np.linalg.norm(v0[bad][rows] - v0[cols], axis=1)  # the input's length of each edge
            # a place whose edges to the neighbours exceed `verify_stretch` x the longest in the input is not taken:
            # put out of a crease, a vertex can land centimetres from its neighbours (a spike)
            limit = np.zeros(len(bad))
            np.maximum.at(limit, rows, given)
            limit[limit == 0] = np.inf  # a vertex in no face (a real file can carry such) has no edge to stretch
            cap = min(self.verify_stretch, SNAP_STRETCH) if last else self.verify_stretch
            best, best_out, best_len = v[bad].copy(), np.zeros(len(bad), dtype=bool), cap * limit
            if self.rest_length is not None:  # with a rest shape, no edge may become over SNAP_STRETCH x its rest
                rest_cap = SNAP_STRETCH * pairs.data  # length unless the input already had it that long
                capped = given <= rest_cap
            # the third round also tries a margin of SNAP_MARGIN x eps: in a crease, eps outside one part can be
            # inside the other, and the bisector's way out centimetres from the neighbours
            tries, missing = [(start, 1.0) for start in (v[bad], anchored)], None
            for start, margin in tries + ([(v[bad], SNAP_MARGIN), (anchored, SNAP_MARGIN)] if last else []):
                x, q = self._put_out(start, surface, body, normals, tree, margin)
                length = np.linalg.norm(x[rows] - v[cols], axis=1)
                longest = np.zeros(len(bad))
                np.maximum.at(longest, rows, length)
                take = (q >= 0) & (longest < best_len)
                if self.rest_length is not None:
                    over = np.zeros(len(bad), dtype=bool)
                    np.logical_or.at(over, rows, capped & (length > rest_cap))
                    take &= ~over
                if margin != 1.0:  # only where the full margin's tries (all before these) found no place
                    missing = ~best_out if missing is None else missing
                    take &= missing
                best[take], best_out[take], best_len[take] = x[take], True, longest[take]
            if not best_out.any():
                stuck = True
                continue
            if last:  # straight there: moves of a few mm (the edge cap keeps it from spanning a crease alone)
                v, region = v.copy(), bad[best_out]
                v[region] = best[best_out]
            else:  # the smooth step of the refinement carries the neighbours along: no single edge spans the move
                v, region = self._solve(v, bad[best_out], best[best_out])
            sd[region] = surface.query(body, normals, v[region], tree, k=self.verify_k)[0]
            put += int(np.count_nonzero(best_out))
        return v, put

    def refine_frame(self, garment: np.ndarray, body: np.ndarray, surface: Collider,
                     report: RefineReport) -> np.ndarray:
        """garment (N, 3), body (M, 3) -> refined garment (N, 3) float64; appends to `report`."""
        v0 = np.asarray(garment, dtype=np.float64)
        body = np.asarray(body, dtype=np.float64)
        normals = surface.normals(body)
        tree = body_tree(body)
        v = v0
        sd, cp, n = surface.query(body, normals, v, tree)

        def step(v: np.ndarray, inside: np.ndarray, targets: np.ndarray) -> np.ndarray:
            out, region = self._solve(v, inside, targets)
            sd[region], cp[region], n[region] = surface.query(body, normals, out[region], tree)  # only what moved
            return out

        before = int(np.count_nonzero(sd < 0))
        was_outside = sd >= 0

        def aim(inside: np.ndarray) -> np.ndarray:
            # a vertex the smooth solve dragged in goes back where it was outside, not through the limb
            return np.where(was_outside[inside][:, None], v0[inside], cp[inside] + self.eps * n[inside])

        it, progressive = 0, False
        inside = np.nonzero(sd < 0)[0]
        if self.tear is not None and len(inside):
            targets = self._untorn_targets(v, inside, aim(inside), sd, surface, body, normals, tree)
            if targets is not None:
                progressive = True
                v = step(v, inside, targets)
                it += 1
        while it < self.max_iterations and np.any(sd < 0):
            inside = np.nonzero(sd < 0)[0]
            v = step(v, inside, aim(inside))
            it += 1
        if np.any(sd < 0):
            progressive = True
            # cloth that was outside in the input goes back there; the rest is placed front by front
            back = np.nonzero((sd < 0) & was_outside)[0]
            inside, targets = self._progressive_targets(v, sd, surface, body, normals, tree, only=~was_outside)
            inside, targets = np.concatenate([inside, back]), np.concatenate([targets, v0[back]])
            order = np.argsort(inside)
            v = step(v, inside[order], targets[order])
            if np.any(sd < 0):  # one step to settle what the smooth solve left inside
                inside = np.nonzero(sd < 0)[0]
                v = step(v, inside, aim(inside))
                it += 1
        if self.rest_length is None:
            v, relieved = self._relieve(v0, v, sd, cp, n, surface, body, normals, tree)
        else:  # the edge-limit pass takes the relief pass's place
            v, relieved = self._limit_stretch(v0, v, sd, cp, n, surface, body, normals, tree)
        v, verified = self._verify(v0, v, sd, surface, body, normals, tree)
        report.inside_before.append(before)
        report.inside_after.append(int(np.count_nonzero(sd < 0)))
        report.iterations.append(it)
        report.max_displacement.append(float(np.linalg.norm(v - v0, axis=1).max()))
        report.progressive.append(progressive)
        report.relieved.append(relieved)
        report.verified.append(verified)
        return v


def refine(garment: np.ndarray, faces: np.ndarray, body: np.ndarray, body_faces: np.ndarray,
           eps: float = EPS, max_iterations: int = MAX_ITERATIONS, tear: float | None = 0.02,
           relief_iterations: int = RELIEF_ITERATIONS, verify_k: int = VERIFY_K) -> tuple[np.ndarray, RefineReport]:
    """Refine a garment stream: (T, N, 3) garment, (T, M, 3) body -> ((T, N, 3) float32, report).

    eps: margin outside the body (m); tear: edge elongation (m) above which a patch's closest-point
    targets are checked against front-by-front placement (None: closest points only);
    relief_iterations: rounds of the stretch relief pass (0: none); verify_k: the last check's nearest body
    vertices (0: no check).
    """
    g = np.asarray(garment)
    b = np.asarray(body)
    if g.ndim == 2:
        g, b = g[None], (b[None] if b.ndim == 2 else b)
    refiner = Refiner(faces, g.shape[1], eps=eps, max_iterations=max_iterations, tear=tear,
                      relief_iterations=relief_iterations, verify_k=verify_k)
    surface = BodySurface(body_faces, b.shape[1], far_k=FAR_K)
    report = RefineReport()
    out = np.stack([refiner.refine_frame(g[t], b[t], surface, report) for t in range(len(g))])
    return out.astype(np.float32), report


def naive_push(garment: np.ndarray, body: np.ndarray, surface: Collider, eps: float = EPS) -> np.ndarray:
    """The baseline: move each inside vertex to its closest body point + eps n, nothing else."""
    body = np.asarray(body, dtype=np.float64)
    v = np.asarray(garment, dtype=np.float64).copy()
    sd, cp, n = surface.query(body, surface.normals(body), v)
    inside = sd < 0
    v[inside] = cp[inside] + eps * n[inside]
    return v


def added_jitter_mm(before: np.ndarray, after: np.ndarray) -> float:
    """Mean per-vertex frame-to-frame motion that refinement added (mm): ||d(after) - d(before)||, (T, N, 3)."""
    d = np.diff(np.asarray(after, np.float64), axis=0) - np.diff(np.asarray(before, np.float64), axis=0)
    return float(np.linalg.norm(d, axis=-1).mean() * 1e3)
