"""Triangle-mesh structure: normals, edges, Laplacians, the padded neighbour table.

vertices: (N, 3) or (T, N, 3) float, metres; faces: (F, 3) integer indices.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components as graph_components
from scipy.spatial import cKDTree


def face_normals(vertices: np.ndarray, faces: np.ndarray, normalize: bool = True) -> np.ndarray:
    """(..., N, 3), (F, 3) -> (..., F, 3); area-weighted (2x area) when not normalised."""
    v = np.asarray(vertices)
    f = np.asarray(faces)
    # per coordinate, per corner: contiguous (..., F) arrays; `take` gathers far faster than v[..., f, :]
    x, y, z = (np.ascontiguousarray(v[..., c]) for c in range(3))
    a, b, c = (np.ascontiguousarray(f[:, k]) for k in range(3))
    e1 = [w.take(b, axis=-1) - w.take(a, axis=-1) for w in (x, y, z)]
    e2 = [w.take(c, axis=-1) - w.take(a, axis=-1) for w in (x, y, z)]
    n = np.stack([e1[1] * e2[2] - e1[2] * e2[1],
                  e1[2] * e2[0] - e1[0] * e2[2],
                  e1[0] * e2[1] - e1[1] * e2[0]], axis=-1)
    if normalize:
        n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-20)
    return n


def vertex_face_incidence(faces: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """(N, F) sparse matrix, 1 where vertex n is a corner of face f."""
    f = np.asarray(faces)
    rows = f.reshape(-1)
    cols = np.repeat(np.arange(len(f)), 3)
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(num_vertices, len(f)))


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, incidence: sp.csr_matrix | None = None) -> np.ndarray:
    """Area-weighted unit vertex normals: (..., N, 3), (F, 3) -> (..., N, 3).

    incidence: `vertex_face_incidence(faces, N)`, when the caller keeps one for many frames.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    fn = face_normals(v, f, normalize=False)  # (..., F, 3)
    N = v.shape[-2]
    # (N, F) incidence matrix times face normals: a sparse GEMM instead of a scatter
    inc = vertex_face_incidence(f, N) if incidence is None else incidence
    if fn.ndim == 2:
        vn = inc @ fn
    else:
        lead = fn.shape[:-2]
        flat = np.moveaxis(fn.reshape((-1,) + fn.shape[-2:]), 0, 1).reshape(len(f), -1)
        vn = (inc @ flat).reshape(N, -1, 3)
        vn = np.moveaxis(vn, 1, 0).reshape(lead + (N, 3))
    return vn / np.maximum(np.sqrt(np.einsum("...c,...c->...", vn, vn))[..., None], 1e-20)


WELD_TOLERANCE_M = 1e-6  # vertices closer than this (per coordinate, in every frame) are one


def coincident_groups(points: np.ndarray, tol: float = WELD_TOLERANCE_M) -> tuple[np.ndarray, np.ndarray]:
    """Vertices at one place: points (N, 3), or (N, 3T) for T frames side by side -> (first (M,) the index
    of each group's first vertex, in order of first appearance; group (N,) each vertex's group). Two vertices
    are together when every coordinate differs by at most `tol` (in every frame); groups are the connected
    chains of such pairs. UV seams and hard edges duplicate vertices at one position: such a mesh is one
    surface, not several."""
    x = np.asarray(points, dtype=np.float64)
    pairs = cKDTree(x[:, :3]).query_pairs(tol, p=np.inf, output_type="ndarray")
    if len(pairs) and x.shape[1] > 3:
        pairs = pairs[np.abs(x[pairs[:, 0]] - x[pairs[:, 1]]).max(axis=1) <= tol]
    n = len(x)
    if not len(pairs):
        return np.arange(n), np.arange(n)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = graph_components(graph, directed=False)
    _, first, inverse = np.unique(label, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return first[order], rank[inverse.ravel()]


def weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge coincident vertices (`coincident_groups`): (N, 3), (F, 3) -> (welded vertices (M, 3), welded faces (F', 3) without
    the faces that collapse, group (N,): vertex i of the input is welded vertex group[i], so that
    `welded[group]` restores per-vertex arrays). With no coincident vertices it returns the input unchanged
    (group = arange(N))."""
    first, group = coincident_groups(vertices)
    return np.asarray(vertices)[first], regroup_faces(faces, group), group


def mean_edge_length(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Mean length (in the vertices' units) of the mesh's unique edges."""
    v, e = np.asarray(vertices, dtype=np.float64), unique_edges(faces)
    return float(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1).mean())


def densify(vertices: np.ndarray, faces: np.ndarray, edge_length: float,
            max_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint subdivision (trimesh's: each triangle into 4, a new vertex on every edge) of a mesh (N, 3),
    (F, 3), level after level while its mean edge length is above `edge_length` and the next level stays
    within `max_vertices` -> (vertices (M, 3), faces (F', 3)); the first N vertices are the input's, unmoved.
    """
    import trimesh

    v, f = np.asarray(vertices), np.asarray(faces)
    while mean_edge_length(v, f) > edge_length and len(v) + len(unique_edges(f)) <= max_vertices:
        v, f = trimesh.remesh.subdivide(v, f)
    return v, f


def regroup_faces(faces: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Faces (F, 3) re-indexed by `group` (N,) (see `weld`), without the faces that collapse -> (F', 3)."""
    f = group[np.asarray(faces, dtype=np.int64)]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return f[keep].astype(np.asarray(faces).dtype)


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """(F, 3) -> (E, 2) int64 edges, each once, with e[:, 0] < e[:, 1], sorted."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0)


def edge_face_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique edges (E, 2) and how many faces use each (E,)."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    edges, counts = np.unique(e, axis=0, return_counts=True)
    return edges, counts


def is_edge_manifold(faces: np.ndarray) -> bool:
    """True when every edge is used by one (boundary) or two faces."""
    _, counts = edge_face_counts(faces)
    return bool(np.all(counts <= 2))


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """(B, 2) edges used by exactly one face."""
    edges, counts = edge_face_counts(faces)
    return edges[counts == 1]


def boundary_vertices(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """(N,) bool: the vertices on a boundary edge (hems, cuffs, openings)."""
    out = np.zeros(num_vertices, dtype=bool)
    out[boundary_edges(faces).ravel()] = True
    return out


def adjacency_matrix(faces: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """Symmetric (N, N) 0/1 vertex adjacency."""
    e = unique_edges(faces)
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_vertices, num_vertices))
    return (a + a.T).tocsr()


def uniform_laplacian(faces: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """L = I - D^-1 A: (L @ V)_i = v_i - mean of its neighbours. Isolated vertices get 0 rows."""
    a = adjacency_matrix(faces, num_vertices)
    deg = np.asarray(a.sum(axis=1)).ravel()
    inv = np.where(deg > 0, 1.0 / np.maximum(deg, 1), 0.0)
    return (sp.diags((deg > 0).astype(float)) - sp.diags(inv) @ a).tocsr()


def cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Cotangent-weight Laplacian L (N, N), positive semi-definite, rows summing to 0.

    L_ij = -(cot a_ij + cot b_ij) / 2 for edges, L_ii = -sum_j L_ij (no mass matrix).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    N = len(v)
    rows, cols, vals = [], [], []
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        # angle at corner k, opposite edge (i, j)
        u = v[f[:, i]] - v[f[:, k]]
        w = v[f[:, j]] - v[f[:, k]]
        cot = np.einsum("fc,fc->f", u, w) / np.maximum(np.linalg.norm(np.cross(u, w), axis=1), 1e-20)
        rows += [f[:, i], f[:, j]]
        cols += [f[:, j], f[:, i]]
        vals += [-0.5 * cot, -0.5 * cot]
    off = sp.coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(N, N)
    ).tocsr()
    diag = -np.asarray(off.sum(axis=1)).ravel()
    return (off + sp.diags(diag)).tocsr()


def neighbour_table(faces: np.ndarray, num_vertices: int,
                    max_neighbours: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Padded one-ring table for ONNX-safe graph convolution (gather + weighted sum).

    Returns (indices (N, K) int64, weights (N, K) float32), K the largest vertex degree: row i lists
    vertex i's neighbours with weight 1/deg(i); padding entries point at i itself
    with weight 0, so `sum_k w[i, k] * x[idx[i, k]]` is the neighbour mean.

    max_neighbours: K at most this; a vertex with more neighbours keeps `max_neighbours` of them, evenly spaced
    in index order, each weighted 1/max_neighbours (its mean over that subset). The table and what a network
    gathers through it are N x K: one vertex joined to thousands (a fan, an n-gon, corners welded onto one point)
    would otherwise make every row that long.
    """
    a = adjacency_matrix(faces, num_vertices).tocsr()
    deg = np.diff(a.indptr)
    kmax = max(int(deg.max(initial=0)), 1)
    keep = np.ones(a.nnz, dtype=bool)
    if max_neighbours is not None and kmax > max_neighbours:
        for i in np.flatnonzero(deg > max_neighbours):  # the few over the cap: evenly spaced picks
            picked = np.linspace(0, deg[i] - 1, max_neighbours).round().astype(np.int64)
            keep[a.indptr[i]:a.indptr[i + 1]] = False
            keep[a.indptr[i] + picked] = True
        deg = np.minimum(deg, max_neighbours)
        kmax = max_neighbours
    idx = np.repeat(np.arange(num_vertices)[:, None], kmax, axis=1).astype(np.int64)
    wts = np.zeros((num_vertices, kmax), dtype=np.float32)
    slot = np.arange(int(deg.sum())) - np.repeat(np.cumsum(deg) - deg, deg)
    row = np.repeat(np.arange(num_vertices), deg)
    idx[row, slot] = a.indices[keep]
    wts[row, slot] = 1.0 / deg[row]
    return idx, wts


def face_adjacency(faces: np.ndarray) -> np.ndarray:
    """(A, 2) pairs of faces sharing an edge (interior edges of a manifold mesh)."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    face_id = np.tile(np.arange(len(f)), 3)
    order = np.lexsort((e[:, 1], e[:, 0]))
    e, face_id = e[order], face_id[order]
    same = np.all(e[1:] == e[:-1], axis=1)
    return np.stack([face_id[:-1][same], face_id[1:][same]], axis=1)


def connected_components(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """(N,) component label per vertex (vertices joined by edges)."""
    from scipy.sparse.csgraph import connected_components as cc

    _, labels = cc(adjacency_matrix(faces, num_vertices), directed=False)
    return labels
