"""Body-garment proximity queries.

Two signed distances, both positive outside the body and negative inside:

* `signed_distance_nearest_vertex`: DeePSD's test, (x - b_j) . n_j with b_j the
  nearest body vertex and n_j its normal. Cheap, approximate.
* `signed_distance_to_mesh`: the exact closest point on the body's triangles,
  signed with the normal interpolated at that point (barycentric blend of
  vertex normals). Exact in the distance, robust in the sign on closed bodies.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from drape.geometry.mesh import vertex_normals


def signed_distance_nearest_vertex(
    points: np.ndarray, body_vertices: np.ndarray, body_normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """points: (P, 3); body_vertices, body_normals: (M, 3).

    Returns (signed distance (P,) metres, nearest body vertex index (P,)).
    """
    tree = cKDTree(body_vertices)
    _, idx = tree.query(points)
    d = np.einsum("pc,pc->p", points - body_vertices[idx], body_normals[idx])
    return d, idx


def closest_point_on_triangles(
    points: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on each triangle (a_i, b_i, c_i) to points_i (Ericson, RTCD 5.1.5).

    All inputs (P, 3). Returns (closest points (P, 3), barycentric coords (P, 3)).
    """
    ab, ac, ap = b - a, c - a, points - a
    bp, cp = points - b, points - c
    d1 = np.einsum("pc,pc->p", ab, ap)
    d2 = np.einsum("pc,pc->p", ac, ap)
    d3 = np.einsum("pc,pc->p", ab, bp)
    d4 = np.einsum("pc,pc->p", ac, bp)
    d5 = np.einsum("pc,pc->p", ab, cp)
    d6 = np.einsum("pc,pc->p", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    tiny = 1e-30
    # default: interior of the face; v, w: the weights of b and c
    denom = 1.0 / np.maximum(va + vb + vc, tiny)
    v, w = vb * denom, vc * denom
    # a point in several regions' tests takes the last: the most specific (vertex) regions come last
    e43, e56 = d4 - d3, d5 - d6
    m = (va <= 0) & (e43 >= 0) & (e56 >= 0)  # edge bc
    t = e43 / np.maximum(e43 + e56, tiny)
    v, w = np.where(m, 1 - t, v), np.where(m, t, w)
    m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)  # edge ac
    t = d2 / np.maximum(d2 - d6, tiny)
    v, w = np.where(m, 0.0, v), np.where(m, t, w)
    m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)  # edge ab
    t = d1 / np.maximum(d1 - d3, tiny)
    v, w = np.where(m, t, v), np.where(m, 0.0, w)
    for m, vv, ww in (((d6 >= 0) & (d5 <= d6), 0.0, 1.0),  # vertex c
                      ((d3 >= 0) & (d4 <= d3), 1.0, 0.0),  # vertex b
                      ((d1 <= 0) & (d2 <= 0), 0.0, 0.0)):  # vertex a
        v, w = np.where(m, vv, v), np.where(m, ww, w)
    bary = np.stack([1 - v - w, v, w], axis=1)
    # a zero-area triangle (corners at one place, or on one line) is the segments between its corners, where the
    # region tests above read rounding noise (an edge of length 0 passes its region's tests for every point)
    # va + vb + vc = |ab x ac|^2 and (d1 - d3) (d2 - d6) = |ab|^2 |ac|^2: exactly 0 <= 0 when two corners coincide
    flat = np.nonzero(va + vb + vc <= 1e-12 * (d1 - d3) * (d2 - d6))[0]
    if len(flat):
        bary[flat] = _closest_on_edges(points[flat], a[flat], b[flat], c[flat])
    closest = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    return closest, bary


def _closest_on_edges(points: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coords (P, 3) of the closest point to points (P, 3) on the edges ab, bc, ca of triangles (P, 3)."""
    best, out = np.full(len(points), np.inf), np.empty((len(points), 3))
    for i, j in ((0, 1), (1, 2), (2, 0)):
        s, e = (a, b, c)[i], (a, b, c)[j]
        d = e - s
        t = np.clip(np.einsum("pc,pc->p", points - s, d) / np.maximum(np.einsum("pc,pc->p", d, d), 1e-300), 0.0, 1.0)
        r = points - s - t[:, None] * d
        dist = np.einsum("pc,pc->p", r, r)
        take = dist < best
        best[take] = dist[take]
        out[take] = 0.0
        out[take, i], out[take, j] = 1 - t[take], t[take]
    return out


class MeshDistance:
    """Exact closest-point queries against one triangle mesh (e.g. a posed body).

    vertices: (M, 3) metres; faces: (F, 3). Triangles are split into classes by
    size (centroid-to-corner radius); each class has a KD-tree on its centroids.
    A query is exact because, within a class, a triangle whose centroid lies
    farther than (best distance + the class's largest radius) cannot be closer;
    points whose candidate list does not reach that bound are re-queried with
    more candidates. The answer is the best over the classes. Distances are exact
    up to `exact_within` metres; a point farther away than that gets a distance
    that is an upper bound, itself above `exact_within` (what collision and
    clearance tests need, at a fraction of the cost).
    """

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        normals: np.ndarray | None = None,
        exact_within: float = 0.05,
    ):
        self.exact_within = exact_within
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.normals = vertex_normals(self.vertices, self.faces) if normals is None else normals
        tri = self.vertices[self.faces]  # (F, 3, 3)
        centroids = tri.mean(axis=1)
        radius = np.linalg.norm(tri - centroids[:, None], axis=2).max(axis=1)
        edges = np.unique(np.quantile(radius, [0.0, 0.5, 0.9, 1.0]))
        cls = np.clip(np.searchsorted(edges, radius, side="left") - 1, 0, None)
        self.classes = []
        for c in np.unique(cls):
            ids = np.nonzero(cls == c)[0]
            self.classes.append((ids, cKDTree(centroids[ids]), float(radius[ids].max())))

    def _exact_for(self, points: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, ...]:
        P, C = cand.shape
        f = self.faces[cand.reshape(-1)]
        pts = np.repeat(points, C, axis=0)
        cp, bary = closest_point_on_triangles(
            pts, self.vertices[f[:, 0]], self.vertices[f[:, 1]], self.vertices[f[:, 2]]
        )
        d2 = np.einsum("pc,pc->p", pts - cp, pts - cp).reshape(P, C)
        best = np.argmin(d2, axis=1)
        rows = np.arange(P) * C + best
        return bary[rows], cand[np.arange(P), best], np.sqrt(d2[np.arange(P), best])

    def project(self, points: np.ndarray, k: int = 8, exact: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """points: (P, 3) -> (closest face index (P,), barycentric coords of the closest point (P, 3)).

        exact=False stops after the k nearest centroids of each class: faster, and
        right for all but a few points near large triangles.
        """
        pts = np.asarray(points, dtype=np.float64)
        P = len(pts)
        bary = np.empty((P, 3))
        face = np.empty(P, dtype=np.int64)
        dist = np.full(P, np.inf)
        for ids, tree, radius in self.classes:
            todo = np.arange(P)
            kk = k
            while len(todo):
                kk = min(kk, len(ids))
                cdist, cand = tree.query(pts[todo], k=kk)
                cand = ids[cand.reshape(len(todo), -1)]
                cdist = cdist.reshape(len(todo), -1)
                b_, f_, d_ = self._exact_for(pts[todo], cand)
                better = d_ < dist[todo]
                upd = todo[better]
                bary[upd], face[upd], dist[upd] = b_[better], f_[better], d_[better]
                # a farther centroid of this class could hide a closer triangle only within dist + radius
                reach = np.minimum(dist[todo], self.exact_within) + radius
                sure = (kk == len(ids)) | (cdist[:, -1] >= reach) | (not exact)
                todo = todo[~sure]
                kk *= 4
        return face, bary

    def closest(self, points: np.ndarray, exact: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """points: (P, 3) -> (closest points (P, 3), interpolated unit normals (P, 3), face index (P,))."""
        face, bary = self.project(points, exact=exact)
        corners = self.faces[face]
        cp = np.einsum("pk,pkc->pc", bary, self.vertices[corners])
        n = np.einsum("pk,pkc->pc", bary, self.normals[corners])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
        return cp, n, face

    def signed_distance(self, points: np.ndarray, exact: bool = True) -> np.ndarray:
        """(P, 3) -> (P,) metres: |x - p| signed by the side of the normal at p (negative inside)."""
        pts = np.asarray(points, dtype=np.float64)
        cp, n, _ = self.closest(pts, exact=exact)
        diff = pts - cp
        dist = np.linalg.norm(diff, axis=1)
        side = np.einsum("pc,pc->p", diff, n)
        return np.where(side < 0, -dist, dist)


class OpenSurfaceDistance:
    """Exact signed distance to an open, thin triangle surface (a garment layer), one topology, any pose.

    faces (F, 3) int and num_vertices: the surface's topology (edges and boundary are found once). `frame(vertices
    (N, 3) m)` builds the per-pose search structure; `query(points (P, 3))` on the last frame answers
    (signed distance (P,) m, closest point (P, 3), pseudo-normal there (P, 3), covered (P,) bool).

    The side is taken from the pseudo-normal at the closest point (the face's normal inside a face, the sum of the
    two faces' on an edge, the angle-weighted vertex normal at a vertex: exact, Baerentzen and Aanaes 2005, where
    an interpolated vertex normal flips sign at creases for points centimetres away). covered: the closest point
    is not on the surface's boundary (hems, cuffs, necklines, an open front), where no side is defined, and lies
    within `reach` (MeshDistance is exact within it)."""

    def __init__(self, faces: np.ndarray, num_vertices: int, reach: float = 0.1):
        F = np.asarray(faces, dtype=np.int64)
        n = int(num_vertices)
        self.faces, self.n, self.reach = F, n, float(reach)
        # the edge opposite corner j of each face, as a key into the unique edges
        a_, b_ = F[:, [1, 2, 0]], F[:, [2, 0, 1]]
        keys = np.minimum(a_, b_) * n + np.maximum(a_, b_)  # (F, 3)
        edge_key, edge_index, counts = np.unique(keys.ravel(), return_inverse=True, return_counts=True)
        self.edge_key, self.edge_index = edge_key, edge_index.reshape(F.shape)
        self.boundary_edge = counts == 1
        self.boundary_vertex = np.zeros(n, dtype=bool)
        self.boundary_vertex[edge_key[self.boundary_edge] // n] = True
        self.boundary_vertex[edge_key[self.boundary_edge] % n] = True
        self.vertices: np.ndarray | None = None

    def pseudo_normals(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """vertices (N, 3) -> face unit normals (F, 3), edge normals (E, 3: the sum of the adjacent faces'),
        angle-weighted unit vertex normals (N, 3)."""
        tri = vertices[self.faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-20)
        en = np.zeros((len(self.edge_key), 3))
        for j in range(3):
            np.add.at(en, self.edge_index[:, j], fn)
        vn = np.zeros_like(vertices)
        for j in range(3):
            a = tri[:, (j + 1) % 3] - tri[:, j]
            b = tri[:, (j + 2) % 3] - tri[:, j]
            cos = np.einsum("fc,fc->f", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1),
                                                           1e-20)
            np.add.at(vn, self.faces[:, j], np.arccos(np.clip(cos, -1.0, 1.0))[:, None] * fn)
        return fn, en, vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-20)

    def frame(self, vertices: np.ndarray) -> OpenSurfaceDistance:
        """Set the pose the next queries measure against: vertices (N, 3) m. Returns self."""
        v = np.asarray(vertices, dtype=np.float64)
        self.vertices = v
        self.normals = self.pseudo_normals(v)
        self.distance = MeshDistance(v, self.faces, normals=self.normals[2], exact_within=self.reach)
        return self

    def query(self, points: np.ndarray, exact: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """points (P, 3) -> (signed distance (P,) m, closest point (P, 3), unit pseudo-normal (P, 3), covered (P,)).
        exact=False: MeshDistance.project's faster search (the nearest centroids only)."""
        if self.vertices is None:
            raise RuntimeError("call frame(vertices) before query")
        x = np.asarray(points, dtype=np.float64)
        v, F = self.vertices, self.faces
        fn, en, vn = self.normals
        face, bary = self.distance.project(x, exact=exact)
        zero = bary < 1e-9
        nz = zero.sum(axis=1)
        cp = np.einsum("pk,pkc->pc", bary, v[F[face]])
        diff = x - cp
        dist = np.linalg.norm(diff, axis=1)
        edge = self.edge_index[face, zero.argmax(axis=1)]  # the edge opposite the zero corner (nz == 1)
        corner = F[face, bary.argmax(axis=1)]  # the vertex (nz == 2)
        nrm = np.where((nz == 0)[:, None], fn[face], np.where((nz == 1)[:, None], en[edge], vn[corner]))
        nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-20)
        sd = np.where(np.einsum("pc,pc->p", diff, nrm) < 0, -dist, dist)
        on_boundary = ((nz == 1) & self.boundary_edge[edge]) | ((nz >= 2) & self.boundary_vertex[corner])
        return sd, cp, nrm, ~on_boundary & (dist <= self.reach)


def signed_distance_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Exact signed distance of points (P, 3) to the mesh (vertices (M, 3), faces (F, 3)): (P,) metres."""
    return MeshDistance(vertices, faces).signed_distance(points)


def nearest_vertex_weights(points: np.ndarray, body_vertices: np.ndarray, body_weights: np.ndarray) -> np.ndarray:
    """Skin weights copied from the nearest body vertex: (P, 3), (M, 3), (M, K) -> (P, K) float32.

    The plain baseline for skinning a garment: cheap, but it tears loose cloth
    (a skirt between the legs takes the left and right thighs' weights).
    """
    _, idx = cKDTree(body_vertices).query(points)
    return np.asarray(body_weights, dtype=np.float32)[idx]


def winding_number(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, batch: int = 64) -> np.ndarray:
    """Generalised winding number of a closed triangle mesh at points (P, 3) -> (P,) float.

    The sum of the triangles' signed solid angles over 4 pi (Van Oosterom & Strackee): about 1
    inside, 0 outside, and k where k closed parts of a self-intersecting mesh overlap. Unlike a
    closest-triangle sign it sees a point inside one body part whose nearest surface belongs to
    another part (a posed body that intersects itself at the armpits or thighs). Brute force,
    O(P F): a diagnostic, too slow for per-frame use on a full body (minutes for a few frames of a
    6k-vertex garment at F = 27k, see bench/refine_self_intersection.py).
    """
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]  # (F, 3 corners, 3)
    pts = np.asarray(points, dtype=np.float64)
    out = np.empty(len(pts))
    for i in range(0, len(pts), batch):
        rel = tri[None] - pts[i:i + batch, None, None]  # (B, F, 3, 3)
        a, b, c = rel[:, :, 0], rel[:, :, 1], rel[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("pfc,pfc->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfc,pfc->pf", a, b) * lc
               + np.einsum("pfc,pfc->pf", b, c) * la + np.einsum("pfc,pfc->pf", c, a) * lb)
        out[i:i + batch] = np.arctan2(det, den).sum(axis=1) / (2 * np.pi)
    return out


CANDIDATE_STRIDE = 4  # candidate_joints and loose_points read every 4th body vertex


def loose_points(points: np.ndarray, body_vertices: np.ndarray, loose_beyond: float,
                 stride: int = CANDIDATE_STRIDE) -> np.ndarray:
    """(P, 3), (M, 3) m -> (P,) bool: the points farther than `loose_beyond` metres from every `stride`-th body
    vertex (loose cloth: candidate_joints' `loose_beyond` rule, for callers without its neighbour query;
    candidate_joints compares the nearest distance of the query it already runs, rather than a second one on
    the rig's path; tests/geometry/test_candidate_joints.py pins that the two agree)."""
    d0 = cKDTree(np.asarray(body_vertices)[::stride]).query(np.asarray(points, dtype=np.float64), workers=-1)[0]
    return np.asarray(d0 > loose_beyond)


def candidate_joints(points: np.ndarray, body_vertices: np.ndarray, body_weights: np.ndarray,
                     influences: int = 4, margin: float = 0.03, relative_margin: float = 0.5,
                     neighbours: int = 128, stride: int = CANDIDATE_STRIDE, chunk: int = 8192, parents: np.ndarray | None = None,
                     loose_beyond: float | None = None) -> np.ndarray:
    """The joints a garment point may be skinned to: (P, 3), (M, 3) m, (M, K) -> (P, K) bool, at most
    `influences` True per row.

    The body's skin weights are averaged over the body vertices about as near as the nearest one (within
    d0 + max(margin, relative_margin * d0) metres of the point, d0 its nearest distance, among its
    `neighbours` nearest of every `stride`-th body vertex: the average needs no more), and the `influences`
    largest joints of that average are kept. Near the skin this is
    the skin's own joints; cloth hanging between body parts (a skirt between the legs) sees both parts. A
    rig restricted to these joints keeps a sleeve on the arm's joints, and engines that play 4 influences a
    vertex play it exactly.

    loose_beyond (metres; needs `parents` (K,), the skeleton's parent of each joint, -1 at the root): a point
    farther than that from the body keeps the `influences` - 1 largest joints and their lowest common ancestor
    (when it is not among them already), so that a long skirt's hem between the knees may also follow the
    pelvis instead of only the legs' joints.
    """
    pts = np.asarray(points, dtype=np.float64)
    w = np.asarray(body_weights, dtype=np.float32)[::stride]
    tree = cKDTree(np.asarray(body_vertices)[::stride])
    k = min(neighbours, len(w))
    mask = np.zeros((len(pts), w.shape[1]), dtype=bool)
    if loose_beyond is not None and influences >= 2 and parents is None:
        raise ValueError("loose_beyond needs the skeleton's parents")
    for s in range(0, len(pts), chunk):
        d, idx = tree.query(pts[s:s + chunk], k=k, workers=-1)
        d, idx = d.reshape(len(d), k), idx.reshape(len(idx), k)
        d0 = d[:, :1]
        near = (d <= d0 + np.maximum(margin, relative_margin * d0)).astype(np.float32)  # (c, k)
        # the sum of the near vertices' weights as a sparse (c, M) @ (M, K) product (an einsum over the
        # gathered (c, k, K) weights was 30x slower)
        pick = sparse.csr_matrix((near.ravel(), idx.ravel(), np.arange(0, near.size + 1, k)), shape=(len(d), len(w)))
        avg = np.asarray(pick @ w)
        top = np.argsort(-avg, axis=1, kind="stable")[:, :influences]
        rows = np.arange(len(avg))[:, None]
        keep = avg[rows, top] > 1e-4 * near.sum(axis=1, keepdims=True)
        if loose_beyond is not None and influences >= 2 and parents is not None:
            loose = np.flatnonzero(d0[:, 0] > loose_beyond)  # loose_points' rule, on the distances at hand
            ancestor = lowest_common_ancestor(parents, top[loose, : influences - 1], keep[loose, : influences - 1])
            new = ~(top[loose, : influences - 1] == ancestor[:, None]).any(axis=1)
            top[loose[new], influences - 1] = ancestor[new]
            keep[loose[new], influences - 1] = True
        mask[s + rows, top] = keep
    return mask


def lowest_common_ancestor(parents: np.ndarray, joints: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """parents (K,) (-1 at the root); joints (P, J) int, valid (P, J) bool (at least the first of each row) ->
    (P,) int: each row's deepest joint that is an ancestor (or the joint itself) of every valid joint of the row."""
    parents = np.asarray(parents)
    k = len(parents)
    chain = [[j] for j in range(k)]  # each joint's ancestors, itself first
    for j in range(k):
        while parents[chain[j][-1]] >= 0:
            chain[j].append(int(parents[chain[j][-1]]))
    pair = np.zeros((k, k), dtype=np.int64)  # pair[a, b]: the lowest common ancestor of a and b
    for a in range(k):
        for b in range(k):
            pair[a, b] = next(x for x in chain[a] if x in chain[b])
    out = np.asarray(joints)[:, 0].astype(np.int64)
    for c in range(1, joints.shape[1]):
        out = np.where(valid[:, c], pair[out, joints[:, c]], out)
    return out
