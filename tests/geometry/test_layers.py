"""Refinement between layers: the inner layer as a thick, open collider; the outer pushed out of it."""

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.geometry.layers import LAYER_EPS, BodyAndLayerSurface, LayerSurface, refine_layers
from drape.geometry.lbs import pose_mesh
from drape.geometry.queries import nearest_vertex_weights, signed_distance_to_mesh
from drape.geometry.refine import BodySurface
from drape.sim.layers import split_outfit
from drape.sim.quality import INSIDE_BAND, outer_inner_distance

BODY = load_body("neutral")


def sheet(n: int = 11, half: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A square sheet in the z = 0 plane, normals +z: vertices (n*n, 3) m, faces (2 (n-1)^2, 3)."""
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def test_the_inner_layer_is_a_collider_offset_by_its_thickness():
    """Signed distances to the sheet offset by H_in = 6 mm: in front closer than H_in and behind it are
    inside, farther in front is outside; past the sheet's edge and deeper behind than the band nothing is
    judged (outside); the closest point lies on the offset surface."""
    v, f = sheet()
    surface = LayerSurface(f, len(v), thickness=0.006)
    assert np.allclose(surface.normals(v), [0, 0, 1])
    pts = np.array([[0.01, 0.02, 0.003], [0.01, 0.02, 0.010], [0.01, 0.02, -0.010],
                    [0.01, 0.02, -0.050], [0.15, 0.0, -0.005]])
    sd, cp, _ = surface.query(v, surface.normals(v), pts)
    assert np.allclose(sd[:3], [-0.003, 0.004, -0.016], atol=1e-9)
    assert np.all(sd[3:] > 0)
    assert np.allclose(cp[0], [0.01, 0.02, 0.006])


def test_body_and_layer_collider_answers_for_the_deeper_surface():
    """A 'body' sheet at z = 0 and an inner sheet at z = 1 cm (H_in 6 mm) as one collider: each point gets the
    smaller of the body's distance less (3 mm - LAYER_EPS) and the offset inner's, and that surface's closest point
    and normal; the body's part keeps 3 mm from it once the refiner adds LAYER_EPS."""
    v, f = sheet()
    inner = v + [0, 0, 0.01]
    surface = BodyAndLayerSurface(BodySurface(f, len(v)), len(v), f, len(v), thickness=0.006, body_eps=0.003)
    both = np.concatenate([v, inner])
    normals = surface.normals(both)
    assert normals.shape == both.shape
    shift = 0.003 - LAYER_EPS
    pts = np.array([[0.01, 0.02, 0.012], [0.01, 0.02, 0.001], [0.01, 0.02, -0.004], [0.01, 0.02, 0.05]])
    sd, cp, n = surface.query(both, normals, pts)
    body_sd, layer_sd = pts[:, 2] - shift, pts[:, 2] - 0.01 - 0.006
    layer_sd[2] = -0.014 - 0.006  # 14 mm behind the inner: within the 3 cm band
    assert np.allclose(sd, np.minimum(body_sd, layer_sd), atol=1e-9)
    assert np.allclose(cp[:, 2], np.where(layer_sd < body_sd, 0.016, shift), atol=1e-9)
    assert np.allclose(n, [0, 0, 1])


def test_refine_layers_pushes_the_outer_out_of_the_inner_and_both_out_of_the_body():
    """A t-shirt under a jacket, each posed by the nearest-body-weights LBS baseline on a held-out clip: they
    penetrate the body and each other. After refine_layers: <= 0.1% of either inside the body, the outer
    behind the inner (the simulation's L-Coll measure) under 0.1% (the issue's bar after refinement), and the
    refiners' own count of outer vertices closer to the inner than H_in at most 0.1% after the last pass.
    Measured: L-Coll 1.72% -> 0.00%, H-Coll 2.1% / 3.6% -> 0.04% / 0.02%."""
    (vi, fi), (vo, fo) = split_outfit("tshirt,jacket", 1500, seed=3)
    clip = load_clip("dance_b")
    frames = np.arange(0, clip.num_frames, 30)
    p, t = clip.poses[frames].astype(float), clip.trans[frames].astype(float)
    body = BODY.pose(p, t)
    inner, outer = (pose_mesh(x, nearest_vertex_weights(x, BODY.vertices, BODY.weights), BODY.joints, p, t)
                    for x in (vi, vo))

    def l_coll(o, i):
        sd, covered = outer_inner_distance(o, i, fi)
        return float(np.mean(covered & (sd < 0) & (sd >= -INSIDE_BAND)))

    def h_coll(x):
        return float(np.mean([np.mean(signed_distance_to_mesh(a, b, BODY.faces) < 0) for a, b in
                              zip(x, body, strict=True)]))

    before = l_coll(outer, inner)
    assert before > 0.005 and h_coll(inner) > 0.005 and h_coll(outer) > 0.005, "the input should penetrate"
    ri, ro, report = refine_layers(inner, fi, outer, fo, body, BODY.faces, thickness=0.006)
    assert ri.shape == inner.shape and ro.shape == outer.shape and ri.dtype == np.float32
    assert h_coll(ri) <= 0.001 and h_coll(ro) <= 0.001
    after = l_coll(ro, ri)
    assert after <= 0.001, (before, after)
    assert sum(report.outer_in_inner_before) > 0
    assert sum(report.outer_in_inner_after) <= 0.001 * outer.shape[0] * outer.shape[1]




def test_the_pass_between_layers_takes_no_place_across_a_fold_of_the_inner():
    """The served t-shirt + jacket at frame 32 of kick (H_in 8 mm). The pass of the outer against the inner had no
    stretch cap on its last check (the two other passes have LAYER_VERIFY_STRETCH): it put jacket vertices out
    of a fold of the t-shirt across it, an edge 19 cm longer than posed (kick's worst frame for that pass; a
    probe found the same on another frame, 12 cm). With the cap 38 mm (asserted: under 10 cm), and nothing is left
    behind the inner."""
    from drape.geometry.layers import LayerRefiner, LayerReport
    from drape.geometry.mesh import unique_edges
    from drape.runtime.engine import Engine

    clip = load_clip("kick")
    p, t = clip.poses.astype(np.float32), clip.trans.astype(np.float32)
    engine = Engine(refine_workers=1)
    try:
        combo = engine.layers.find("tshirt", "jacket")
        parts = list(engine.layer_chunks(combo, 0.008, p, t, chunk=64))
    finally:
        engine.close()
    inner = np.concatenate([i for i, _ in parts])[32].astype(np.float64)
    outer = np.concatenate([o for _, o in parts])[32].astype(np.float64)
    faces_o = combo.outer.faces
    refiner = LayerRefiner(combo.inner.faces, len(inner), faces_o, len(outer), 0.008, BODY.faces, len(BODY.vertices))
    report, stages = LayerReport(), []
    refiner.refine_frame(inner, outer, BODY.pose(p[32:33], t[32:33])[0].astype(np.float64), report, stages)
    edges = unique_edges(faces_o)
    given = np.linalg.norm(outer[edges[:, 0]] - outer[edges[:, 1]], axis=1)
    between = stages[1]  # after the outer against the inner
    stretch = np.linalg.norm(between[edges[:, 0]] - between[edges[:, 1]], axis=1) - given
    assert report.outer_in_inner_before[0] > 0 and report.outer_in_inner_after[0] == 0
    assert stretch.max() < 0.10, stretch.max()
