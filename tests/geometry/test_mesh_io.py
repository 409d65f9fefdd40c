"""Mesh files: named parts written as OBJ objects read back as one mesh in order, and as the service's parts."""

import numpy as np
import pytest

from drape.geometry.mesh_io import load_mesh, obj_parts, save_mesh

VERTICES = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [0, 1, 1], [1, 0, 1]], np.float32) * 0.1
FACES = np.array([[0, 1, 2], [0, 2, 1], [3, 4, 5], [5, 4, 6], [3, 6, 4]], np.int32)


def test_an_obj_with_parts_reads_back_as_the_same_mesh_and_as_named_parts(tmp_path):
    path = save_mesh(tmp_path / "two.obj", VERTICES, FACES, [("shirt", 0, 3), ("coat", 3, 7)])
    v, f = load_mesh(path)
    np.testing.assert_array_equal(v, VERTICES)
    assert sorted(map(tuple, f.tolist())) == sorted(map(tuple, FACES.tolist()))
    assert obj_parts(path.read_bytes(), path.name, len(v)) == [
        {"name": "shirt", "start": 0, "stop": 3}, {"name": "coat", "start": 3, "stop": 7}]


def test_parts_that_do_not_cover_the_vertices_or_share_a_face_are_refused(tmp_path):
    with pytest.raises(ValueError, match="do not cover"):
        save_mesh(tmp_path / "a.obj", VERTICES, FACES, [("shirt", 0, 3), ("coat", 4, 7)])
    with pytest.raises(ValueError, match="two parts"):
        save_mesh(tmp_path / "b.obj", VERTICES, np.vstack([FACES, [[2, 3, 4]]]), [("shirt", 0, 3), ("coat", 3, 7)])
    assert not (tmp_path / "a.obj").exists() and not (tmp_path / "b.obj").exists()


def test_other_formats_ignore_parts(tmp_path):
    v, f = load_mesh(save_mesh(tmp_path / "two.ply", VERTICES, FACES, [("shirt", 0, 3), ("coat", 3, 7)]))
    np.testing.assert_allclose(v, VERTICES, atol=1e-7)
    assert len(f) == len(FACES)
