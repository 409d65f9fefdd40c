"""Mesh files (OBJ, PLY, GLB/glTF) through trimesh, as plain arrays.

vertices: (N, 3) float32 metres; faces: (F, 3) int32. Vertex order is kept as
stored (no merging or reordering), so per-vertex results map back to the file.
"""

from __future__ import annotations

import io
import re
import warnings
from pathlib import Path
from typing import BinaryIO, cast

import numpy as np

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")


def read_trimesh(source: str | BinaryIO, file_type: str | None = None):  # noqa: ANN201 (a trimesh.Trimesh)
    """trimesh's reader as drape uses it (one mesh, vertices in the file's order, nothing merged), without the
    numpy RuntimeWarnings ("All-NaN slice encountered") trimesh's texture code prints on OBJ files whose faces
    name texture coordinates the file lacks (the ArcSim tops of ../shared/data/external): the geometry is read
    and checked all the same. Raises whatever trimesh raises on a broken file."""
    import trimesh

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return cast(trimesh.Trimesh, trimesh.load(source, file_type=file_type, process=False, force="mesh",
                                                  maintain_order=True))


def read_trimesh_parts(source: BinaryIO, file_type: str):  # noqa: ANN201 (a trimesh.Trimesh, parts)
    """A scene file (glTF) read as `read_trimesh` reads it (its meshes placed and concatenated, nothing merged),
    with the named parts: [{"name", "start", "stop"}] vertex ranges of the concatenated mesh, one per placed mesh
    (named by its node), in the order trimesh concatenates them; None for a single mesh."""
    import trimesh

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        scene = cast(trimesh.Scene, trimesh.load(source, file_type=file_type, process=False, force="scene",
                                                 maintain_order=True))
    pieces = [p for p in scene.dump(concatenate=False) if isinstance(p, trimesh.Trimesh)]
    if not pieces:
        raise ValueError("the scene places no triangle mesh")
    if len(pieces) == 1:
        return pieces[0], None
    stops = np.cumsum([len(p.vertices) for p in pieces])
    parts = [{"name": str(p.metadata.get("node") or p.metadata.get("name") or "")[:200], "start": int(start),
              "stop": int(stop)} for p, start, stop in zip(pieces, [0, *stops[:-1]], stops, strict=True)]
    return trimesh.util.concatenate(pieces), parts


_MATERIAL_LINES = re.compile(rb"(?m)^[ \t]*(?:usemtl|mtllib)\b[^\n]*")


def without_materials(data: bytes) -> bytes:
    """An OBJ's bytes without its `usemtl` and `mtllib` lines. Materials are not read, and trimesh's reader
    (maintain_order) gives each `usemtl` block a copy of every vertex: a two-material garment came back with its
    vertices twice over, each material's faces on their own copy (the garment cut apart at every material
    border), and a 1,000-block file of 20,000 `v` lines built 20 million vertices."""
    return _MATERIAL_LINES.sub(b"", data) if b"mtl" in data else data


_RELATIVE_FACE = re.compile(rb"(?m)^[ \t]*f[ \t][^\n]*-")
# the element lines of an OBJ (v, vt, vn, f and their rest), found in C: blank and comment lines are skipped there,
# so a file padded with millions of them costs a scan, not a Python object per line
_ELEMENT = re.compile(rb"(?m)^[ \t]*(vt|vn|v|f)[ \t]([^\n]*)")


def _spliced(data: bytes, edits: list[tuple[int, int, bytes]]) -> bytes:
    """data with each (start, stop, new bytes) span replaced (spans in order, not overlapping)."""
    out, at = [], 0
    for start, stop, new in edits:
        out += [data[at:start], new]
        at = stop
    out.append(data[at:])
    return b"".join(out)


def absolute_indices(data: bytes) -> bytes:
    """An OBJ's faces with their relative (negative) indices made absolute: -1 is the last `v` (`vt`, `vn`)
    before the face. trimesh counts them back from the end of the file, which moves every face of an object but
    the last onto the last object's vertices (faces lost, no error). Files without them come back as they are.
    ValueError for a relative index reaching before the first element of its kind (or -0)."""
    if not _RELATIVE_FACE.search(data):
        return data
    counts = {b"v": 0, b"vt": 0, b"vn": 0}
    edits = []
    for m in _ELEMENT.finditer(data):
        key, rest = m.group(1), m.group(2)
        if key != b"f":
            counts[key] += 1
            continue
        if b"-" not in rest:
            continue
        corners = []
        for corner in rest.split():
            refs = corner.split(b"/")
            for k, (ref, kind) in enumerate(zip(refs, (b"v", b"vt", b"vn"), strict=False)):
                if ref.startswith(b"-") and ref[1:].isdigit() and len(ref) <= 19:  # longer: left for the reader
                    absolute = counts[kind] + 1 + int(ref)
                    if absolute < 1 or int(ref) == 0:
                        raise ValueError(f"a face's relative index {ref.decode()} reaches before the first "
                                         f"'{kind.decode()}' line ({counts[kind]} come before it)")
                    refs[k] = str(absolute).encode()
            corners.append(b"/".join(refs))
        edits.append((m.start(2), m.end(2), b" ".join(corners) + (b"\r" if rest.endswith(b"\r") else b"")))
    return _spliced(data, edits)


def load_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh; several meshes in one file (glTF scenes) are concatenated.

    A file that is not there or cannot be opened: OSError naming it. A suffix trimesh does not read, a file it
    cannot parse, one without a triangle, faces indexing past the vertices or vertices that are not finite:
    ValueError naming the file (not trimesh's IndexError, nor an empty mesh that draws nothing)."""

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported mesh suffix {path.suffix!r}; use one of {MESH_SUFFIXES}")
    with open(path, "rb"):  # FileNotFoundError / IsADirectoryError / PermissionError, with the path
        pass
    try:
        if path.suffix.lower() == ".obj":  # one vertex per `v` line (without_materials), relative faces kept right
            data = absolute_indices(without_materials(path.read_bytes()))
            mesh = read_trimesh(io.BytesIO(data), file_type="obj")
        else:
            mesh = read_trimesh(str(path))
    except Exception as exc:  # noqa: BLE001 - trimesh's parsers raise anything (IndexError, KeyError, ...)
        raise ValueError(f"{path}: not a readable {path.suffix.lower()[1:].upper()} mesh "
                         f"({type(exc).__name__}: {exc})") from exc
    vertices = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float32)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:  # a file of points or lines reads as an empty mesh: its vertex count would say 0
        raise ValueError(f"{path}: the file holds no triangle faces" + (f" ({len(vertices)} vertices)" if len(vertices)
                                                                         else " (points or lines only?)"))
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"{path}: faces index vertices {faces.min()}..{faces.max()}; the mesh has "
                         f"{len(vertices)}")
    if not np.isfinite(vertices).all():
        raise ValueError(f"{path}: vertices hold NaN or infinite values (or values beyond float32)")
    return vertices, faces.astype(np.int32)


def save_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray,
              parts: list[tuple[str, int, int]] | None = None) -> Path:
    """Write a triangle mesh; the format follows the file's suffix.

    parts: named vertex ranges (name, start, stop), in order and covering every vertex, each face within one
    range (several garments as one mesh). An OBJ then holds one `o name` object per range, its `v` and then its
    `f` lines, which the service reads back as the rig's `parts` (`obj_parts`); the
    vertex order is kept. Other formats ignore parts."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"unsupported mesh suffix {path.suffix!r}; use one of {MESH_SUFFIXES}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if parts and path.suffix.lower() == ".obj":
        _save_obj_parts(path, np.asarray(vertices), np.asarray(faces), parts)
        return path
    trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), process=False).export(str(path))
    return path


def _save_obj_parts(path: Path, vertices: np.ndarray, faces: np.ndarray, parts: list[tuple[str, int, int]]) -> None:
    bounds = [(start, stop) for _, start, stop in parts]
    if bounds[0][0] != 0 or bounds[-1][1] != len(vertices) or any(
            a[1] != b[0] for a, b in zip(bounds, bounds[1:], strict=False)):
        raise ValueError(f"parts {bounds} do not cover the {len(vertices)} vertices in order")
    stops = np.array([stop for _, _, stop in parts])
    owner = np.searchsorted(stops, faces, side="right")  # the part of each face's corners
    if (owner != owner[:, :1]).any():
        raise ValueError("a face joins vertices of two parts")
    lines = []
    for k, (name, start, stop) in enumerate(parts):
        lines.append(f"o {name}")
        lines += obj_lines(vertices[start:stop], faces[owner[:, 0] == k])
    path.write_text("\n".join(lines) + "\n")


def obj_lines(vertices: np.ndarray, faces: np.ndarray) -> list[str]:
    """A mesh's OBJ `v` lines (vertices (N, 3), 9 significant digits: float32 read back exactly) then its `f`
    lines (faces (F, 3), 0-based indices written 1-based as they are)."""
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.asarray(vertices, np.float64).tolist()]
    return lines + [f"f {a} {b} {c}" for a, b, c in (np.asarray(faces, np.int64) + 1).tolist()]


def rewrite_obj(data: bytes, vertices: np.ndarray, normal_turn: np.ndarray | None = None) -> tuple[bytes, str]:
    """An OBJ file's bytes with its `v` lines moved to `vertices` (N, 3) (in the file's order, as `load_mesh`
    reads them) and every other line kept: texture coordinates, materials (mtllib, usemtl), objects, groups,
    smoothing groups, comments, a vertex's extra values (w, or colours).

    normal_turn: (3, 3), the linear map the geometry went through (a similarity): each `vn` is turned by its
    inverse transpose and made unit length. None: the file's normals no longer fit the geometry (e.g. sleeves
    un-posed), so the `vn` lines and the faces' normal indices are left out (a DCC tool smooths them again).
    -> (the new bytes, what became of the normals: "turned", "dropped" or "none in the file").

    ValueError when the file's `v` lines are not N (a line continued with a backslash, or another mesh), or a
    `vn` line is not three numbers.
    """
    if b"\\\n" in data or b"\\\r\n" in data:
        raise ValueError("the OBJ continues lines with a backslash; its v lines are not the vertices read")
    count = sum(1 for m in _ELEMENT.finditer(data) if m.group(1) == b"v")
    if count != len(vertices):
        raise ValueError(f"the OBJ's v lines ({count}) are not the {len(vertices)} vertices read from it")
    turn = None if normal_turn is None else np.linalg.inv(np.asarray(normal_turn, np.float64)).T
    has_normals = False
    edits: list[tuple[int, int, bytes]] = []
    i = 0
    for m in _ELEMENT.finditer(data):
        key, rest = m.group(1), m.group(2)
        end = b"\r" if rest.endswith(b"\r") else b""
        words = rest.split()
        if key == b"v":
            x, y, z = (float(c) for c in vertices[i])
            edits.append((m.start(), m.end(), b" ".join([f"v {x:.9g} {y:.9g} {z:.9g}".encode(), *words[3:]]) + end))
            i += 1
        elif key == b"vn":
            has_normals = True
            if turn is None:
                edits.append((m.start(), min(m.end() + 1, len(data)), b""))  # the line and its newline
                continue
            try:
                n = turn @ np.array([float(c) for c in words[:3]], np.float64).reshape(3)
            except ValueError:
                raise ValueError(f"a vn line is not three numbers: {rest[:40]!r}") from None
            n /= max(float(np.linalg.norm(n)), 1e-12)
            edits.append((m.start(), m.end(), f"vn {n[0]:.7g} {n[1]:.7g} {n[2]:.7g}".encode() + end))
        elif key == b"f" and turn is None:
            corners = [c.split(b"/") for c in words]
            edits.append((m.start(), m.end(), b" ".join([b"f", *(b"/".join(c[:2]).rstrip(b"/") for c in corners)])
                          + end))
    said = "none in the file" if not has_normals else "turned" if turn is not None else "dropped"
    return _spliced(data, edits), said


def obj_uv_corners(data: bytes, faces: np.ndarray, max_uvs: int | None = None) -> np.ndarray | None:
    """The texture coordinates of an OBJ's face corners, as `faces` (F, 3) (the triangles `load_mesh` read from
    it, in the file's order: polygons fanned from their first corner) -> (F, 3, 2) float32 (OBJ's convention: v
    up from the image's bottom), or None: the file has no `vt` (or more than max_uvs), a face without them, an
    index out of range (0 included), a value that is not a finite number, or triangles that do not match
    `faces`.

    Read here because trimesh's reader, keeping the file's vertex order, drops them. A vertex on a UV seam has
    one texture coordinate per face around it: corners, not vertices. Memory: 16 bytes a `vt`, 48 a triangle."""
    from array import array

    if b"vt" not in data or (max_uvs is not None and data.count(b"vt") > max_uvs):
        return None
    if b"\\\n" in data or b"\\\r\n" in data:
        data = data.replace(b"\\\r\n", b"").replace(b"\\\n", b"")
    uvs, tri_v, tri_t = array("d"), array("q"), array("q")
    count = 0  # v lines so far (relative indices count back from here)
    try:
        for m in _ELEMENT.finditer(data):
            key = m.group(1)
            if key == b"v":
                count += 1
            elif key == b"vt":
                words = m.group(2).split()
                uvs.extend((float(words[0]), float(words[1]) if len(words) > 1 else 0.0))
            elif key == b"f":
                corners = []
                for c in m.group(2).split():
                    ids = c.split(b"/")
                    if len(ids) < 2 or not ids[1]:
                        return None  # a face without texture coordinates
                    v, t = int(ids[0]), int(ids[1])
                    if v == 0 or t == 0:
                        return None
                    corners.append((v - 1 if v > 0 else count + v, t - 1 if t > 0 else len(uvs) // 2 + t))
                for a, b in zip(corners[1:-1], corners[2:], strict=True):
                    tri_v.extend((corners[0][0], a[0], b[0]))
                    tri_t.extend((corners[0][1], a[1], b[1]))
    except (ValueError, IndexError):
        return None
    file_v = np.frombuffer(tri_v, np.int64).reshape(-1, 3)
    file_t = np.frombuffer(tri_t, np.int64).reshape(-1, 3)
    faces = np.asarray(faces, np.int64)
    if file_v.shape != faces.shape or len(faces) == 0:
        return None
    refs = np.full(faces.shape, -1, np.int64)
    for r in range(3):  # trimesh may start a fanned triangle at another corner: the rotation that matches
        rolled = np.roll(file_v, -r, axis=1)
        match = (rolled == faces).all(axis=1) & (refs[:, 0] < 0)
        refs[match] = np.roll(file_t, -r, axis=1)[match]
    table = np.frombuffer(uvs, np.float64).reshape(-1, 2)
    if refs.min() < 0 or refs.max() >= len(table):
        return None
    corners_uv = table[refs].astype(np.float32)
    return corners_uv if np.isfinite(corners_uv).all() else None


def obj_parts(data: bytes, filename: str, num_vertices: int) -> list[dict] | None:
    """The named parts of a mesh file's bytes, in the order of the file, as vertex ranges of what `load_mesh`
    (and the service's upload reader) read: [{"name", "start", "stop"}, ...] (stop exclusive), or None for a
    single part.

    OBJ: each `o` object (or, in a file without them, each `g` group) holds the `v` lines that follow it,
    which the reader keeps in the file's order. Other formats: None (their parts are not yet mapped).
    """
    if not filename.lower().endswith(".obj"):
        return None
    text = data.replace(b"\r\n", b"\n").replace(b"\\\n", b"")
    lines = text.split(b"\n")
    key = b"o" if any(line.startswith((b"o ", b"o\t")) for line in lines) else b"g"
    parts: list[dict] = []
    count = 0
    for line in lines:
        word = line.split(None, 1)
        if not word:
            continue
        if word[0] == b"v":
            count += 1
        elif word[0] == key:
            name = word[1].strip().decode("utf-8", "replace")[:200] if len(word) > 1 else ""
            parts.append({"name": name, "start": count, "stop": count})
        if parts:
            parts[-1]["stop"] = count
    if parts and parts[0]["start"] > 0:
        parts.insert(0, {"name": "", "start": 0, "stop": parts[0]["start"]})
    parts = [p for p in parts if p["stop"] > p["start"]]
    if len(parts) < 2 or parts[-1]["stop"] != num_vertices:  # a file read otherwise than counted: no parts
        return None
    return parts
