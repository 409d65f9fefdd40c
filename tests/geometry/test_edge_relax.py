"""Edge-length relaxation (drape.geometry.edge_relax) against closed forms and invariants: one free edge is
restored exactly, held vertices do not move, rigid motions commute with it, and a noisy mesh's edge error falls
round after round."""

import numpy as np
from scipy.spatial.transform import Rotation

from drape.assets.outfits import generate_outfit
from drape.geometry.edge_relax import relax_edges
from drape.geometry.mesh import unique_edges
from drape.geometry.metrics import edge_lengths


def noisy_tshirt(frames: int = 5, sigma: float = 0.003):
    o = generate_outfit("tshirt", vertices=800, seed=4)
    e = unique_edges(o.faces)
    x = o.vertices[None] + np.random.default_rng(1).normal(0, sigma, (frames, len(o.vertices), 3))
    return x, e, edge_lengths(o.vertices, e)


def test_one_free_edge_takes_its_rest_length_in_one_round_and_keeps_its_midpoint():
    x = np.array([[[0.0, 0.0, 0.0], [0.3, 0.4, 0.0]]])  # length 0.5
    y = relax_edges(x, np.array([[0, 1]]), np.array([0.2]), 1)
    assert np.isclose(np.linalg.norm(y[0, 1] - y[0, 0]), 0.2, atol=1e-6)
    assert np.allclose(y[0].mean(axis=0), x[0].mean(axis=0), atol=1e-6)


def test_a_held_end_stays_and_the_other_takes_the_whole_correction():
    x = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]]])
    y = relax_edges(x, np.array([[0, 1]]), np.array([0.25]), 1, fixed=np.array([[True, False]]))
    assert np.array_equal(y[0, 0], x[0, 0]) and np.allclose(y[0, 1], [0.0, 0.0, 0.25], atol=1e-6)


def test_zero_rounds_is_the_input_and_held_vertices_never_move():
    x, e, rest = noisy_tshirt()
    assert np.array_equal(relax_edges(x, e, rest, 0), x.astype(np.float32))
    fixed = np.random.default_rng(2).random(x.shape[:2]) < 0.2
    y = relax_edges(x, e, rest, 10, fixed=fixed)
    x32 = x.astype(np.float32)
    assert np.array_equal(y[fixed], x32[fixed]) and not np.allclose(y[~fixed], x32[~fixed])


def test_a_rigid_motion_commutes_with_relaxation():
    x, e, rest = noisy_tshirt(frames=2)
    r = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    t = np.array([0.5, -2.0, 1.0])
    a = relax_edges(x @ r.T + t, e, rest, 8)
    b = relax_edges(x, e, rest, 8) @ r.T + t
    assert np.abs(a - b).max() < 1e-5  # float32 arithmetic: micrometres


def test_the_edge_error_falls_round_after_round():
    x, e, rest = noisy_tshirt()
    errors = [np.abs(edge_lengths(relax_edges(x, e, rest, n), e) - rest).mean() for n in (0, 2, 5, 10, 20)]
    assert all(b < a for a, b in zip(errors, errors[1:], strict=False)), errors
    assert errors[-1] < 0.25 * errors[0], errors
