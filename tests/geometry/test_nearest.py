"""drape.geometry.nearest: the body's KD-tree answers what scipy's cKDTree answers, on one thread."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from drape.geometry.nearest import VertexTree


@pytest.mark.parametrize("k", [1, 2, 5, 8])
def test_same_neighbours_as_ckdtree(k: int) -> None:
    rng = np.random.default_rng(3)
    vertices = rng.normal(size=(5000, 3)) * 0.2
    points = np.concatenate([rng.normal(size=(3000, 3)) * 0.3, vertices[:50] + 1e-4])  # some on the vertices
    dist, idx = VertexTree(vertices).query(points, k=k)
    ref_dist, ref_idx = cKDTree(vertices).query(points, k=k)
    assert dist.shape == idx.shape == (len(points), k)
    assert idx.dtype == np.int64
    np.testing.assert_array_equal(idx, ref_idx.reshape(len(points), k))
    np.testing.assert_allclose(dist, ref_dist.reshape(len(points), k), rtol=0, atol=1e-15)
    # the distances are those to the vertices named
    np.testing.assert_allclose(dist, np.linalg.norm(points[:, None] - vertices[idx], axis=2), rtol=1e-12)


def test_no_points_and_float32_input() -> None:
    tree = VertexTree(np.eye(3, dtype=np.float32))
    dist, idx = tree.query(np.zeros((0, 3)), k=2)
    assert dist.shape == idx.shape == (0, 2)
    dist, idx = tree.query(np.array([[0.9, 0.0, 0.0]], dtype=np.float32), k=1)
    assert idx.tolist() == [[0]] and dist[0, 0] == pytest.approx(0.1)


def test_fewer_vertices_than_neighbours_asked() -> None:
    """A body of fewer vertices than k (a user body can be that small): every vertex, the farthest repeated,
    never an index past the end (pykdtree's fill), so the refinement's gathers stay in range."""
    tree = VertexTree(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]]))
    dist, idx = tree.query(np.array([[0.1, 0.0, 0.0]]), k=5)
    assert idx.tolist() == [[0, 1, 2, 2, 2]]
    np.testing.assert_allclose(dist[0], [0.1, 0.9, np.hypot(0.1, 2.0), np.hypot(0.1, 2.0), np.hypot(0.1, 2.0)])


def test_a_body_of_few_vertices_refines() -> None:
    """The refinement's queries ask 5 and 8 nearest body vertices: a 4-vertex body (a tetrahedron around the
    garment) is refined without an index error, the point inside put out."""
    from drape.geometry.refine import FAR_K, BodySurface, Refiner, RefineReport

    body = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    body_faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    garment = np.array([[0.2, 0.2, 0.2], [1.0, 1.0, 1.0], [1.2, 1.0, 1.0]])
    surface = BodySurface(body_faces, 4, far_k=FAR_K)
    out = Refiner(np.array([[0, 1, 2]]), 3).refine_frame(garment, body, surface, RefineReport())
    sd = surface.query(body, surface.normals(body), out, k=8)[0]
    assert np.all(sd >= 0), sd


def test_one_thread_and_environment_kept() -> None:
    """A large query starts no OpenMP threads (the refinement pool's processes share the cores), and the
    caller's OMP_NUM_THREADS is what it was after the import."""
    code = (
        "import os, numpy as np\n"
        "from drape.geometry.nearest import VertexTree\n"
        "tree = VertexTree(np.random.default_rng(0).random((20000, 3)))\n"
        "before = len(os.listdir('/proc/self/task'))\n"
        "tree.query(np.random.default_rng(1).random((200000, 3)), k=5)\n"
        "print(before, len(os.listdir('/proc/self/task')), os.environ.get('OMP_NUM_THREADS'))\n"
    )
    if not os.path.isdir("/proc/self/task"):
        pytest.skip("needs /proc to count threads")
    for env, want in ((None, "None"), ("4", "4")):
        e = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
        if env is not None:
            e["OMP_NUM_THREADS"] = env
        out = subprocess.run([sys.executable, "-c", code], env=e, capture_output=True, text=True, check=True)
        before, after, kept = out.stdout.split()
        assert after == before, f"the query started {int(after) - int(before)} thread(s)"
        assert kept == want
