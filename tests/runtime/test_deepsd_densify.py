"""DeePSD reads a mesh coarser than `densify_edge` subdivided and answers for the mesh's own vertices: the same
rows as rigging the subdivided mesh itself; a mesh already fine enough is rigged as it is."""

import numpy as np
import pytest
import trimesh

from drape.assets.body import load_body
from drape.assets.outfits import generate_outfit
from drape.geometry.mesh import mean_edge_length
from drape.runtime.deepsd import DeePSDModel


@pytest.fixture(scope="module")
def coarse():
    o = generate_outfit("tshirt", vertices=400, seed=5, body="neutral")
    return o.vertices, o.faces


def test_a_coarse_mesh_answers_from_its_subdivision(coarse):
    v, f = coarse
    body = load_body("neutral")
    target = 0.6 * mean_edge_length(v, f)  # one level of midpoint subdivision halves the edges
    rig = DeePSDModel(densify_edge=target, densify_ring=False).rig(v, f, body)
    fine_v, fine_f = trimesh.remesh.subdivide(v, f)
    fine = DeePSDModel(densify_edge=None).rig(fine_v.astype(np.float32), fine_f, body)
    assert rig.weights.shape == (len(v), 24) and rig.blend_shapes.shape[1:] == (len(v), 3)
    assert np.allclose(rig.weights, fine.weights[: len(v)], atol=1e-6)
    assert np.allclose(rig.blend_shapes, fine.blend_shapes[:, : len(v)], atol=1e-7)
    as_is = DeePSDModel(densify_edge=None).rig(v, f, body)
    assert np.abs(as_is.weights - rig.weights).max() > 1e-3  # and the subdivision changed the answer


def test_a_fine_mesh_is_read_as_it_is(coarse):
    v, f = coarse
    body = load_body("neutral")
    a = DeePSDModel(densify_edge=2 * mean_edge_length(v, f)).rig(v, f, body)
    b = DeePSDModel(densify_edge=None).rig(v, f, body)
    assert np.array_equal(a.weights, b.weights) and np.array_equal(a.blend_shapes, b.blend_shapes)


def test_with_the_ring_a_vertex_answers_the_mean_of_itself_and_its_finer_one_ring(coarse):
    from drape.geometry.mesh import adjacency_matrix

    v, f = coarse
    body = load_body("neutral")
    target = 0.6 * mean_edge_length(v, f)
    ring = DeePSDModel(densify_edge=target, densify_ring=True).rig(v, f, body)
    fine_v, fine_f = trimesh.remesh.subdivide(v, f)
    fine = DeePSDModel(densify_edge=None).rig(fine_v.astype(np.float32), fine_f, body)
    adj = adjacency_matrix(fine_f, len(fine_v)).tocsr()
    for i in (0, len(v) // 2, len(v) - 1):  # an independent mean over the sparse adjacency
        nbrs = adj.indices[adj.indptr[i]:adj.indptr[i + 1]]
        expect = 0.5 * (fine.weights[i] + fine.weights[nbrs].mean(axis=0))
        assert np.allclose(ring.weights[i], expect, atol=1e-6)
        expect_d = 0.5 * (fine.blend_shapes[:, i] + fine.blend_shapes[:, nbrs].mean(axis=1))
        assert np.allclose(ring.blend_shapes[:, i], expect_d, atol=1e-7)
    assert np.allclose(ring.weights.sum(axis=1), 1, atol=1e-5)


def test_a_fan_vertex_reads_a_capped_one_ring(monkeypatch):
    """A vertex joined to a hundred others (one n-gon line in an OBJ) made the network's neighbour table, and every
    gather through it, that wide: 0.5 -> 3.7 GB for a 1k-vertex t-shirt. The table is capped at MAX_NEIGHBOURS."""
    from drape.runtime import deepsd

    model = DeePSDModel()
    o = generate_outfit("tshirt", vertices=600, seed=1)
    n = 120
    fan = np.stack([np.zeros(n, np.int64), np.arange(1, n + 1), np.arange(2, n + 2)], axis=1)
    widths = []
    real = deepsd.network_inputs
    monkeypatch.setattr(deepsd, "network_inputs", lambda v, f: widths.append(real(v, f)["nbr_idx"].shape[1])
                        or real(v, f))
    rig = model.rig(o.vertices, np.vstack([o.faces, fan]).astype(np.int32), load_body("neutral"))
    assert widths == [deepsd.MAX_NEIGHBOURS]
    assert np.isfinite(rig.weights).all() and np.allclose(rig.weights.sum(axis=1), 1.0, atol=1e-4)
