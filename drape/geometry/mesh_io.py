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


_MATERIAL_LINES = re.compile(rb"(?m)^[ \t]*(?:usemtl|mtllib)\b[^\n]*")


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


def without_materials(data: bytes) -> bytes:
    """An OBJ's bytes without its `usemtl` and `mtllib` lines. Materials are not read, and trimesh's reader
    (maintain_order) gives each `usemtl` block a copy of every vertex: a two-material garment came back with its
    vertices twice over, each material's faces on their own copy (the garment cut apart at every material
    border), and a 1,000-block file of 20,000 `v` lines built 20 million vertices."""
    return _MATERIAL_LINES.sub(b"", data) if b"mtl" in data else data


_RELATIVE_FACE = re.compile(rb"(?m)^[ \t]*f[ \t][^\n]*-")


def absolute_indices(data: bytes) -> bytes:
    """An OBJ's faces with their relative (negative) indices made absolute: -1 is the last `v` (`vt`, `vn`)
    before the face. trimesh counts them back from the end of the file, which moves every face of an object but
    the last onto the last object's vertices (faces lost, no error). Files without them come back as they are."""
    if not _RELATIVE_FACE.search(data):
        return data
    counts = {b"v": 0, b"vt": 0, b"vn": 0}
    out = []
    for line in data.split(b"\n"):
        words = line.split()
        if words and words[0] in counts:
            counts[words[0]] += 1
        elif words and words[0] == b"f" and b"-" in line:
            corners = []
            for corner in words[1:]:
                refs = corner.split(b"/")
                for k, (ref, key) in enumerate(zip(refs, (b"v", b"vt", b"vn"), strict=False)):
                    if ref.startswith(b"-") and ref[1:].isdigit() and len(ref) <= 19:  # longer: left for the reader
                        refs[k] = str(counts[key] + 1 + int(ref)).encode()
                corners.append(b"/".join(refs))
            line = b" ".join([b"f", *corners]) + (b"\r" if line.endswith(b"\r") else b"")
        out.append(line)
    return b"\n".join(out)


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
        lines.extend(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices[start:stop].tolist())
        lines.extend(f"f {a} {b} {c}" for a, b, c in (faces[owner[:, 0] == k] + 1).tolist())
    path.write_text("\n".join(lines) + "\n")


def rewrite_obj(data: bytes, vertices: np.ndarray, normal_turn: np.ndarray | None = None) -> tuple[bytes, str]:
    """An OBJ file's bytes with its `v` lines moved to `vertices` (N, 3) (in the file's order, as `load_mesh`
    reads them) and every other line kept: texture coordinates, materials (mtllib, usemtl), objects, groups,
    smoothing groups, comments, a vertex's extra values (w, or colours).

    normal_turn: (3, 3), the linear map the geometry went through (a similarity): each `vn` is turned by its
    inverse transpose and made unit length. None: the file's normals no longer fit the geometry (e.g. sleeves
    un-posed), so the `vn` lines and the faces' normal indices are left out (a DCC tool smooths them again).
    -> (the new bytes, what became of the normals: "turned", "dropped" or "none in the file").

    ValueError when the file's `v` lines are not N (a line continued with a backslash, or another mesh).
    """
    text = data.decode("utf-8", "surrogateescape")
    lines = text.split("\n")
    count = sum(1 for line in lines if line.split(None, 1)[:1] == ["v"])
    if count != len(vertices) or "\\\n" in text or "\\\r\n" in text:
        raise ValueError(f"the OBJ's v lines ({count}) are not the {len(vertices)} vertices read from it")
    turn = None if normal_turn is None else np.linalg.inv(np.asarray(normal_turn, np.float64)).T
    has_normals = False
    out, i = [], 0
    for line in lines:
        end = "\r" if line.endswith("\r") else ""
        words = line.rstrip("\r").split()
        key = words[0] if words else ""
        if key == "v":
            x, y, z = (float(c) for c in vertices[i])
            out.append(" ".join([f"v {x:.9g} {y:.9g} {z:.9g}", *words[4:]]) + end)
            i += 1
        elif key == "vn":
            has_normals = True
            if turn is None:
                continue
            n = turn @ np.array([float(c) for c in words[1:4]])
            n /= max(float(np.linalg.norm(n)), 1e-12)
            out.append(f"vn {n[0]:.7g} {n[1]:.7g} {n[2]:.7g}" + end)
        elif key == "f" and turn is None:
            corners = [c.split("/") for c in words[1:]]
            out.append(" ".join(["f", *("/".join(c[:2]).rstrip("/") for c in corners)]) + end)
        else:
            out.append(line)
    said = "none in the file" if not has_normals else "turned" if turn is not None else "dropped"
    return "\n".join(out).encode("utf-8", "surrogateescape"), said


def obj_uv_corners(data: bytes, faces: np.ndarray) -> np.ndarray | None:
    """The texture coordinates of an OBJ's face corners, as `faces` (F, 3) (the triangles `load_mesh` read from
    it: polygons fanned from their first corner) -> (F, 3, 2) float32 (OBJ's convention: v up from the image's
    bottom), or None: the file has no `vt`, a face without them, an index out of range, or triangles that do not
    match `faces`.

    Read here because trimesh's reader, keeping the file's vertex order, drops them. A vertex on a UV seam has
    one texture coordinate per face around it: corners, not vertices."""
    text = data.replace(b"\r\n", b"\n").replace(b"\\\n", b"")
    if b"vt" not in text:
        return None
    uvs: list[tuple[float, float]] = []
    count = 0  # v lines so far (negative indices count back from here)
    by_triangle: dict[tuple[int, int, int], tuple[int, int, int]] = {}
    try:
        for line in text.split(b"\n"):
            words = line.split()
            if not words:
                continue
            key = words[0]
            if key == b"v":
                count += 1
            elif key == b"vt":
                uvs.append((float(words[1]), float(words[2]) if len(words) > 2 else 0.0))
            elif key == b"f":
                corners = []
                for c in words[1:]:
                    ids = c.split(b"/")
                    if len(ids) < 2 or not ids[1]:
                        return None  # a face without texture coordinates
                    v, t = int(ids[0]), int(ids[1])
                    corners.append((v - 1 if v > 0 else count + v, t - 1 if t > 0 else len(uvs) + t))
                for a, b in zip(corners[1:-1], corners[2:], strict=True):
                    tri = (corners[0], a, b)
                    for r in range(3):  # every rotation: trimesh may start a triangle at another corner
                        rot = tri[r:] + tri[:r]
                        by_triangle.setdefault((rot[0][0], rot[1][0], rot[2][0]),
                                               (rot[0][1], rot[1][1], rot[2][1]))
    except (ValueError, IndexError):
        return None
    table = np.asarray(uvs, np.float64).reshape(-1, 2)
    try:
        refs = np.array([by_triangle[(int(a), int(b), int(c))] for a, b, c in np.asarray(faces)], np.int64)
    except KeyError:
        return None
    if refs.size == 0 or refs.min() < 0 or refs.max() >= len(table):
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
