"""Mesh files: named parts written as OBJ objects read back as one mesh in order, and as the service's parts."""

import numpy as np
import pytest

from drape.geometry.mesh_io import load_mesh, obj_parts, rewrite_obj, save_mesh

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


TEXTURED_OBJ = b"""# made in a DCC tool\r
mtllib shirt.mtl\r
o shirt\r
v 0 0 0 1 0 0\r
v 1 0 0\r
v 0 1 0\r
v 1 1 0\r
vt 0 0\r
vt 1 0\r
vt 0 1\r
vt 1 1\r
vn 0 0 1\r
usemtl cotton\r
s 1\r
f 1/1/1 2/2/1 4/4/1 3/3/1\r
f 1//1 3//1 2//1\r
"""


def test_an_obj_rewritten_keeps_every_line_but_the_positions_and_turns_its_normals():
    """Fitting moves vertices; a studio's OBJ keeps its UVs, materials, objects, smoothing groups, a vertex's
    colour and its line endings. Normals turn with the geometry's linear map (the inverse transpose, unit
    length), checked against the moved quad's own normal computed from its corners."""
    v, _ = load_mesh_bytes(TEXTURED_OBJ)
    turn = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]) * 0.01  # Z-up -> Y-up, centimetres -> metres
    moved = v @ turn.T + [0.0, 1.0, 0.0]
    data, normals = rewrite_obj(TEXTURED_OBJ, moved, turn)
    assert normals == "turned"
    old, new = TEXTURED_OBJ.decode().split("\n"), data.decode().split("\n")
    assert len(old) == len(new) and all(a == b for a, b in zip(old, new, strict=True) if not a.startswith("v"))
    assert all(line.endswith("\r") for line in new[:-1]) and new[3].endswith(" 1 0 0\r")  # the colour kept
    again, _ = load_mesh_bytes(data)
    np.testing.assert_allclose(again, moved, atol=1e-7)
    n = np.array([float(c) for c in new[[i for i, line in enumerate(new) if line.startswith("vn")][0]].split()[1:]])
    face = np.cross(moved[1] - moved[0], moved[2] - moved[0])
    np.testing.assert_allclose(n, face / np.linalg.norm(face), atol=1e-6)
    # without a turn (the garment was un-posed: its normals no longer fit) they are left out, faces keep UVs
    data, normals = rewrite_obj(TEXTURED_OBJ, moved)
    text = data.decode()
    assert normals == "dropped" and "vn " not in text and "f 1/1 2/2 4/4 3/3\r" in text and "f 1 3 2\r" in text
    np.testing.assert_allclose(load_mesh_bytes(data)[0], moved, atol=1e-7)
    with pytest.raises(ValueError, match="v lines"):
        rewrite_obj(TEXTURED_OBJ, moved[:3])


def load_mesh_bytes(data: bytes):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.obj"
        path.write_bytes(data)
        return load_mesh(path)


def test_an_obj_with_two_materials_reads_as_one_mesh_in_the_files_order(tmp_path):
    """trimesh's reader (keeping the order) gave each `usemtl` block its own copy of every vertex: a two-material
    garment read by the CLI (outfits fit, render, sim run) had its vertices twice over and was cut apart at the
    material border. The service already read such uploads without their materials; load_mesh does too now."""
    path = tmp_path / "two.obj"
    path.write_text("mtllib x.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\nf 1 2 3\nusemtl b\nf 2 4 3\n")
    v, f = load_mesh(path)
    np.testing.assert_array_equal(v, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert f.tolist() == [[0, 1, 2], [1, 3, 2]]


RELATIVE_OBJ = (b"o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf -3/-3 -2/-2 -1/-1\n"
                b"o b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nvt 0 0.5\nvt 1 0.5\nvt 0 1\nf -3/-3 -2/-2 -1/-1\n")


def test_relative_indices_count_back_from_the_face_not_from_the_end_of_the_file(tmp_path):
    """`f -3 -2 -1` names the three `v` lines before it. trimesh counted back from the end of the file, so every
    object but the last lost its faces to the last one's vertices, without an error (a probe's two-object garment:
    163 of its 196 vertices in faces, 2 faces twice); with `vt` lines among the faces an upload was a 400."""
    from drape.geometry.mesh_io import obj_uv_corners
    from drape.service.uploads import mesh_file

    path = tmp_path / "rel.obj"
    path.write_bytes(RELATIVE_OBJ)
    v, f = load_mesh(path)
    assert f.tolist() == [[0, 1, 2], [3, 4, 5]]
    read = mesh_file(RELATIVE_OBJ, "rel.obj", max_vertices=100, max_faces=100)
    uploaded_v, uploaded_f, uv = read.vertices, read.faces, read.uv_corners
    assert uploaded_f.tolist() == f.tolist() and np.array_equal(uploaded_v, v)
    assert uv is not None and uv[1].tolist() == [[0, 0.5], [1, 0.5], [0, 1]]
    assert np.array_equal(obj_uv_corners(RELATIVE_OBJ, f), uv)
    # a file with its faces written back line for line keeps its relative indices (they stay right)
    data, _ = rewrite_obj(RELATIVE_OBJ, v + 1.0)
    assert data.count(b"f -3/-3 -2/-2 -1/-1") == 2


def test_an_obj_continued_across_lines_is_not_rewritten_line_for_line():
    """A backslash continues a line (LF or CRLF); the rewrite cannot keep it, and says so."""
    for end in (b"\n", b"\r\n"):
        data = b"v 0 1 \\" + end + b"0" + end + b"v 1 0 0" + end + b"v 0 0 1" + end + b"f 1 2 3" + end
        with pytest.raises(ValueError, match="v lines"):
            rewrite_obj(data, np.zeros((3, 3)))


def test_a_relative_index_too_long_for_an_integer_is_a_malformed_file_not_a_crash():
    """absolute_indices leaves a 5,000-digit index to the reader (int() refuses past 4,300 digits: a 500)."""
    from drape.service.errors import MalformedInput
    from drape.service.uploads import mesh_file

    data = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -" + b"9" * 5000 + b"\n"
    with pytest.raises(MalformedInput):
        mesh_file(data, "huge.obj", max_vertices=100, max_faces=100)


def test_obj_text_passes_stay_bounded_on_a_file_padded_with_blank_lines():
    """A probe padded an OBJ with 60 million blank lines and one relative face: the passes that split the file
    into lines held 5 GB and the server was killed. They find the element lines in C now: a 4-million-line
    padding costs a few times the file's bytes."""
    import tracemalloc

    from drape.geometry.mesh_io import absolute_indices, obj_uv_corners

    pad = b"\n" * 4_000_000 + b"# c\n" * 500_000
    data = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n" + pad + b"f -3/-3 -2/-2 -1/-1\n"
    tracemalloc.start()
    absolute = absolute_indices(data)
    uv = obj_uv_corners(absolute, np.array([[0, 1, 2]]))
    moved, _ = rewrite_obj(absolute, np.ones((3, 3)))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert absolute.endswith(b"f 1/1 2/2 3/3\n") and uv is not None and uv[0].tolist() == [[0, 0], [1, 0], [0, 1]]
    assert moved.startswith(b"v 1 1 1\nv 1 1 1\nv 1 1 1\n") and len(moved) == len(absolute)
    assert peak < 6 * len(data), peak


def test_relative_or_zero_indices_that_name_no_element_are_refused_not_guessed():
    """`f -1 -2 -5` after 3 vertices reached before the file's start and became trimesh's -1 (the file's last
    vertex, another object's); `-0` became the next vertex; a `vt` index 0 took the next `vt`."""
    from drape.geometry.mesh_io import absolute_indices, obj_uv_corners

    with pytest.raises(ValueError, match="reaches before the first 'v'"):
        absolute_indices(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -5\nv 0 0 1\n")
    with pytest.raises(ValueError, match="-0"):
        absolute_indices(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -0\n")
    assert obj_uv_corners(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/0 2/0 3/0\nvt 0.25 0.75\n", np.array([[0, 1, 2]])) is None
    ok = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
    assert obj_uv_corners(ok, np.array([[0, 1, 2]])) is not None
    assert obj_uv_corners(ok, np.array([[0, 1, 2]]), max_uvs=2) is None  # more vt lines than asked for
