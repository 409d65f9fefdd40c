"""Body-garment queries and metrics on analytic cases."""

import numpy as np
from shapes import sphere

from drape.geometry.mesh import vertex_normals
from drape.geometry.metrics import (
    bending,
    collision_share,
    edge_length_error_mm,
    hausdorff_mm,
    layer_collision_share,
    max_edge_stretch,
    mean_vertex_error_mm,
    rmse_mm,
    sted,
)
from drape.geometry.queries import (
    MeshDistance,
    closest_point_on_triangles,
    signed_distance_nearest_vertex,
    signed_distance_to_mesh,
    winding_number,
)


def test_closest_point_on_triangle_regions():
    a, b, c = np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    pts = np.array([[0.2, 0.2, 1.0], [-1, -1, 0], [2, -0.5, 0], [0.5, 0.5, 0.3], [-1, 0.5, 0]])
    cp, bary = closest_point_on_triangles(pts, *(np.repeat(x[None], 5, 0) for x in (a, b, c)))
    assert np.allclose(cp, [[0.2, 0.2, 0], [0, 0, 0], [1, 0, 0], [0.5, 0.5, 0], [0, 0.5, 0]])
    assert np.allclose(bary.sum(1), 1)


def test_closest_point_on_a_zero_area_triangle():
    """A sliver whose corners a and b coincide (duplicate vertices, a collapsed face; uploads may hold some) is the
    segment a-c: the closest point lies on it. The zero-length edge ab used to claim every point (its region's
    tests all hold with ab = 0) and answer corner a, up to the whole segment's length too far. A sliver with its
    corners on one line is its longest edge likewise."""
    a, c = np.zeros(3), np.array([1.0, 0, 0])
    pts = np.array([[0.5, 0.2, 0.0], [0.25, 0.0, 0.3], [2.0, 0.1, 0.0], [-1.0, 0.0, 0.0]])
    for tri in ((a, a.copy(), c), (a, c, c.copy()), (a, c, a.copy()), (a, np.array([0.4, 0, 0]), c)):
        cp, bary = closest_point_on_triangles(pts, *(np.repeat(x[None], len(pts), 0) for x in tri))
        assert np.allclose(cp, [[0.5, 0, 0], [0.25, 0, 0], [1, 0, 0], [0, 0, 0]]), tri
        assert np.allclose(bary.sum(1), 1) and np.all(bary >= 0)


def test_exact_distance_matches_brute_force():
    v, f = sphere(1.0, 2)
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(300, 3)) * 0.03 + v[rng.integers(len(v), size=300)]
    md = MeshDistance(v, f)
    cp, _, _ = md.closest(pts)
    d = np.linalg.norm(pts - cp, axis=1)
    # brute force over every triangle
    P, F = len(pts), len(f)
    allcp, _ = closest_point_on_triangles(np.repeat(pts, F, 0), *(np.tile(v[f[:, i]], (P, 1)) for i in range(3)))
    brute = np.linalg.norm(np.repeat(pts, F, 0) - allcp, axis=1).reshape(P, F).min(1)
    assert np.allclose(d, brute, atol=1e-12)


def test_signed_distance_sphere_inside_outside():
    v, f = sphere(1.0, 4)
    radii = np.array([0.5, 0.95, 0.999, 1.01, 1.2, 2.0])
    dirs = np.random.default_rng(1).normal(size=(len(radii), 3))
    pts = dirs / np.linalg.norm(dirs, axis=1, keepdims=True) * radii[:, None]
    sd = signed_distance_to_mesh(pts, v, f)
    assert np.array_equal(sd < 0, radii < 1)
    # exact up to the polyhedral approximation of the sphere (subdiv 4: < 1.3 mm sag at r=1)
    assert np.allclose(sd, radii - 1.0, atol=1.5e-3)
    sdn, _ = signed_distance_nearest_vertex(pts, v, vertex_normals(v, f))
    assert np.array_equal(sdn < 0, radii < 1)


def test_winding_number_sees_inside_where_the_closest_triangle_sign_cannot():
    """Two overlapping unit spheres as one mesh, like a posed body whose arm enters the torso."""
    v, f = sphere(1.0, 3)
    both_v, both_f = np.concatenate([v, v + [1.8, 0, 0]]), np.concatenate([f, f + len(v)])
    pts = np.array([[-0.5, 0, 0], [0.45, 0, 0], [0.9, 0, 0], [3.0, 0, 0], [0.9, 1.5, 0]])
    w = winding_number(pts, both_v, both_f)
    assert np.allclose(w, [1, 1, 2, 0, 0], atol=1e-6)
    # (0.45, 0, 0) is 0.55 inside the first sphere but 0.35 outside the second, which is nearer:
    # the closest-triangle sign calls it outside
    sd = signed_distance_to_mesh(pts, both_v, both_f)
    assert sd[1] > 0.3 and sd[0] < 0
    assert np.allclose(winding_number(pts, v, f), [1, 1, 1, 0, 0], atol=1e-6)


def test_collision_share_counts_inside_vertices():
    v, f = sphere(1.0, 3)
    garment = np.concatenate([v * 0.9, v * 1.1, v[:10] * 1.05])  # 1/2 - ish inside
    expected = len(v) / len(garment)
    for variant in ("triangle", "nearest_vertex"):
        assert abs(collision_share(garment, v, f, variant) - expected) < 1e-12
    frames = np.stack([garment, garment * 2.0])
    assert abs(collision_share(frames, v, f) - expected / 2) < 1e-12


def test_edge_metrics_on_stretched_mesh():
    v, f = sphere(1.0, 2)
    scaled = v * 1.01  # every edge 1% longer
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    mean_len = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1).mean()
    assert np.isclose(edge_length_error_mm(scaled, v, f), mean_len * 0.01 * 1e3)
    assert np.isclose(max_edge_stretch(scaled, v, f), 0.01)
    assert edge_length_error_mm(v, v, f) == 0.0


def test_bending_flat_and_folded():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    f = np.array([[0, 1, 2], [1, 3, 2]])
    assert abs(bending(v, f)) < 1e-12
    folded = v.copy()
    folded[3, 2] = 1.0  # second face tilts; cosine between normals known
    n2 = np.cross(folded[3] - folded[1], folded[2] - folded[1])
    n2 /= np.linalg.norm(n2)
    assert np.isclose(bending(folded, f), 1 - n2[2])


def test_vertex_errors_hausdorff_sted():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(3, 50, 3))
    b = a + np.array([0.003, 0.0, 0.004])
    assert np.isclose(mean_vertex_error_mm(b, a), 5.0)
    assert np.isclose(rmse_mm(b, a), 5.0)
    pa = np.zeros((1, 3))
    pb = np.array([[0.0, 0.0, 0.0], [0.0, 0.02, 0.0]])
    assert np.isclose(hausdorff_mm(pa, pb), 20.0)  # one-sided from b's far point
    v, f = sphere(1.0, 1)
    seq = np.stack([v, v * 1.02, v * 1.04])
    s = sted(seq, seq, f)
    assert s["sted"] == 0.0
    s = sted(seq * 1.1, seq, f)  # uniform scale: relative edge error 10% everywhere, no spread
    assert s["spatial"] < 1e-9 and s["temporal"] > 0


def test_layer_collision_share():
    v, f = sphere(1.0, 3)
    outer = np.concatenate([v * 1.05, v[:20] * 0.97])
    assert np.isclose(layer_collision_share(outer, v, f), 20 / len(outer))


def test_frame_metrics_pair_one_static_frame_with_every_frame_of_the_other_side():
    """The docstrings take (T, ., 3) or (., 3) on each side; a static inner layer (or point set) beside a
    sequence raised (zip strict) instead of being every frame's. Against per-frame copies, the same figures."""
    v, f = sphere(1.0, 3)
    outer = np.stack([np.concatenate([v * 1.05, np.where(np.arange(20)[:, None] < k, v[:20] * 0.97, v[:20] * 1.05)])
                      for k in (0, 10, 20)])
    static = np.broadcast_to(v, (3,) + v.shape)
    assert np.isclose(layer_collision_share(outer, v, f), layer_collision_share(outer, static, f))
    assert np.isclose(layer_collision_share(outer, v, f), 30 / outer[..., 0].size)
    assert np.isclose(layer_collision_share(outer[2], np.stack([v, v * 2.0]), f), (20 + len(outer[2])) / (2 * len(outer[2])))
    assert np.isclose(hausdorff_mm(outer, v), hausdorff_mm(outer, static))
    assert np.isclose(hausdorff_mm(v, outer), hausdorff_mm(static, outer))
    assert np.isclose(collision_share(v * 0.9, np.stack([v, v * 0.8]), f), 0.5)
