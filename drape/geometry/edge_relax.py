"""Edge-length relaxation: posed cloth pulled back toward its rest edge lengths.

Position-based projection, Jacobi style: each round every edge asks both its vertices to move along it so that
its length becomes the rest length (split by their inverse masses: a fixed vertex does not move, its neighbour
takes the whole correction), and each vertex moves by `omega` times the mean of what its edges ask. Frames are
independent. Shapes: vertices (T, N, 3) m; edges (E, 2) vertex indices; rest (E,) m; fixed (T, N) bool.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

FRAME_BLOCK = 16  # frames relaxed at once, at most
EDGE_FRAMES = 1_500_000  # and at most this many edge-frames: an (E, block, 3) float64 array stays under ~36 MB


def relax_edges(vertices: np.ndarray, edges: np.ndarray, rest: np.ndarray, iterations: int,
                fixed: np.ndarray | None = None, omega: float = 1.0, stretch_only: bool = False) -> np.ndarray:
    """`vertices` after `iterations` Jacobi rounds of edge-length projection toward `rest`, vertices where
    `fixed` is True held -> (T, N, 3) float32 m (computed in float32: micrometres of rounding; a held vertex is
    its input in float32). iterations=0 returns the input in float32. stretch_only: only edges longer than their
    rest length are shortened; shorter ones are left as they are."""
    x = np.array(vertices, dtype=np.float32)
    T, N, _ = x.shape
    if iterations <= 0 or len(edges) == 0:
        return x
    e = np.asarray(edges, dtype=np.int64)
    E = len(e)
    rest32 = np.asarray(rest, dtype=np.float32)[:, None]
    # signed incidence (N, E): +1 at an edge's first vertex, -1 at its second; its transpose gathers x_a - x_b
    incidence = sparse.csr_matrix((np.r_[np.ones(E), -np.ones(E)].astype(np.float32),
                                   (np.r_[e[:, 0], e[:, 1]], np.r_[np.arange(E), np.arange(E)])), shape=(N, E))
    gather = incidence.T.tocsr()
    degree = np.maximum(np.bincount(e.ravel(), minlength=N), 1).astype(np.float32)
    free = np.ones((T, N), np.float32) if fixed is None else (~np.asarray(fixed, dtype=bool)).astype(np.float32)
    block = max(1, min(FRAME_BLOCK, EDGE_FRAMES // E))
    for s in range(0, T, block):  # vertex-major (N, t, 3) within a block: gathers and scatters are sparse products
        xb = np.ascontiguousarray(x[s:s + block].transpose(1, 0, 2))
        flat = xb.reshape(N, -1)  # a view: moving xb moves it
        wb = free[s:s + block].T  # (N, t) inverse masses: 0 held, 1 free
        t = xb.shape[1]
        total = wb[e[:, 0]] + wb[e[:, 1]]
        # an edge asks each free end to move by the whole correction over its number of free ends; a held end
        # is then not moved (step 0)
        share = np.divide(1.0, total, out=np.zeros_like(total), where=total > 0)  # (E, t)
        step = (np.float32(omega) / degree)[:, None] * wb  # (N, t): the mean over a vertex's edges, damped
        for _ in range(iterations):
            d = (gather @ flat).reshape(E, t, 3)  # x_a - x_b
            length = np.sqrt(np.einsum("etc,etc->et", d, d))
            excess = length - rest32
            if stretch_only:
                np.maximum(excess, 0.0, out=excess)
            # x_a moves by -c (x_a - x_b), x_b by +c (x_a - x_b): c = excess / length (x its share)
            c = np.divide(excess, length, out=np.zeros_like(length), where=length > 0) * share
            d *= c[..., None]
            delta = (incidence @ d.reshape(E, -1)).reshape(N, t, 3)
            delta *= step[..., None]
            xb -= delta
        x[s:s + block] = xb.transpose(1, 0, 2)
    return x
