"""Normals, edges, Laplacians and the padded neighbour table on meshes with known answers."""

import numpy as np
from shapes import sphere

from drape.geometry.mesh import (
    boundary_edges,
    connected_components,
    cotangent_laplacian,
    densify,
    face_adjacency,
    face_normals,
    is_edge_manifold,
    mean_edge_length,
    neighbour_table,
    uniform_laplacian,
    unique_edges,
    vertex_normals,
)


def test_sphere_normals_point_outward_radially():
    v, f = sphere()
    n = vertex_normals(v, f)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    assert np.min(np.einsum("nc,nc->n", n, v / np.linalg.norm(v, axis=1, keepdims=True))) > 0.995


def test_face_normals_are_the_cross_products_for_one_frame_and_a_batch():
    v, f = sphere(subdiv=1)
    frames = np.stack([v, 2 * v + 1, v[:, [1, 2, 0]]])  # (T, N, 3)
    cross = np.cross(frames[:, f[:, 1]] - frames[:, f[:, 0]], frames[:, f[:, 2]] - frames[:, f[:, 0]])
    assert np.allclose(face_normals(frames, f, normalize=False), cross, rtol=0, atol=1e-12)
    assert np.allclose(face_normals(frames[1], f, normalize=False), cross[1], rtol=0, atol=1e-12)
    unit = face_normals(frames, f)
    assert np.allclose(unit, cross / np.linalg.norm(cross, axis=-1, keepdims=True))


def test_edges_euler_and_manifold():
    v, f = sphere(subdiv=2)
    e = unique_edges(f)
    assert len(v) - len(e) + len(f) == 2  # Euler characteristic of a sphere
    assert is_edge_manifold(f) and len(boundary_edges(f)) == 0
    assert len(face_adjacency(f)) == len(e)
    bad = np.vstack([f, f[:1]])  # a duplicated face makes three faces share its edges
    assert not is_edge_manifold(bad)
    two = np.vstack([f, f + len(v)])
    assert len(np.unique(connected_components(two, 2 * len(v)))) == 2


def test_uniform_laplacian_is_vertex_minus_neighbour_mean():
    v, f = sphere(subdiv=1)
    lap = uniform_laplacian(f, len(v))
    assert np.allclose(lap @ np.ones(len(v)), 0.0)
    idx, w = neighbour_table(f, len(v))
    mean = np.einsum("nk,nkc->nc", w, v[idx])
    assert np.allclose(lap @ v, v - mean)


def test_neighbour_table_padding_and_weights():
    v, f = sphere(subdiv=1)
    idx, w = neighbour_table(f, len(v))
    assert idx.dtype == np.int64 and w.dtype == np.float32
    assert np.allclose(w.sum(axis=1), 1.0)
    pad = w == 0
    assert np.all(idx[pad] == np.nonzero(pad)[0])  # padding points at the vertex itself
    e = {tuple(x) for x in unique_edges(f)}
    for i in range(len(v)):
        for j in idx[i][~pad[i]]:
            assert (min(i, j), max(i, j)) in e


def test_a_capped_neighbour_table_keeps_ordinary_rows_and_an_evenly_spaced_subset_of_a_fan():
    """A vertex joined to 150 others (a fan) makes the table 150 wide; capped at 16 every other row is the
    uncapped one, and the fan's row holds 16 of its true neighbours spread over them, weights 1/16."""
    v, f = sphere(subdiv=2)
    n = 150
    fan = np.stack([np.zeros(n, np.int64), np.arange(1, n + 1), np.arange(2, n + 2)], axis=1)
    faces = np.vstack([f, fan])
    full_idx, full_w = neighbour_table(faces, len(v))
    idx, w = neighbour_table(faces, len(v), max_neighbours=16)
    assert full_idx.shape[1] >= 150 and idx.shape == (len(v), 16) and np.allclose(w.sum(axis=1), 1.0)
    others = np.arange(1, len(v))
    ordinary = full_idx.shape[1] - (full_w[others] == 0).sum(axis=1) <= 16
    rows = others[ordinary]
    assert len(rows) > 0.9 * len(others)
    np.testing.assert_array_equal(np.sort(idx[rows], axis=1), np.sort(full_idx[rows, :16], axis=1))
    truth = set(full_idx[0][full_w[0] > 0].tolist())
    picked = idx[0].tolist()
    assert len(set(picked)) == 16 and set(picked) <= truth and np.allclose(w[0], 1 / 16)
    assert min(picked) == min(truth) and max(picked) == max(truth)  # spread over all of them, not the first 16
    same_idx, same_w = neighbour_table(f, len(v), max_neighbours=16)  # under the cap: exactly the uncapped table
    plain_idx, plain_w = neighbour_table(f, len(v))
    assert np.array_equal(same_idx, plain_idx) and np.array_equal(same_w, plain_w)


def test_cotangent_laplacian_linear_precision_and_sphere_curvature():
    # flat grid: the cotangent Laplacian of a linear function vanishes at interior vertices
    xs, ys = np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 6))
    v = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(36)])
    f = []
    for r in range(5):
        for c in range(5):
            a = r * 6 + c
            f += [[a, a + 1, a + 7], [a, a + 7, a + 6]]
    f = np.array(f)
    lap = cotangent_laplacian(v, f)
    fn = 2 * v[:, 0] - 3 * v[:, 1]
    interior = (xs.ravel() > 0) & (xs.ravel() < 1) & (ys.ravel() > 0) & (ys.ravel() < 1)
    assert np.allclose((lap @ fn)[interior], 0.0, atol=1e-12)
    assert abs((lap - lap.T).max()) < 1e-12
    # on a sphere, L x is parallel to the normal (mean curvature vector)
    vs, fs = sphere(subdiv=3)
    hn = cotangent_laplacian(vs, fs) @ vs
    cos = np.einsum("nc,nc->n", hn, vs) / (np.linalg.norm(hn, axis=1) * np.linalg.norm(vs, axis=1))
    assert cos.min() > 0.99


def test_densify_halves_edges_until_the_target_and_keeps_the_input_vertices_first():
    v, f = sphere(subdiv=1)
    e0 = mean_edge_length(v, f)
    assert densify(v, f, edge_length=2 * e0, max_vertices=10**6)[0] is v  # fine enough: untouched
    dv, df = densify(v, f, edge_length=0.3 * e0, max_vertices=10**6)  # two levels: e0 / 2, e0 / 4
    assert mean_edge_length(dv, df) <= 0.3 * e0 < mean_edge_length(v, f) / 2
    assert np.array_equal(dv[: len(v)], v) and len(df) == 16 * len(f)
    assert is_edge_manifold(df) and len(np.unique(connected_components(df, len(dv)))) == 1
    # edges counted independently: V - E + F = 2 on a sphere at every level
    assert len(dv) - len(unique_edges(df)) + len(df) == 2
    capped, _ = densify(v, f, edge_length=0.3 * e0, max_vertices=len(v) + len(unique_edges(f)))  # one level fits
    assert len(capped) == len(v) + len(unique_edges(f))
