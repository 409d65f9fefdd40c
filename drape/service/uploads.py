"""Uploaded mesh files checked against the limits before any decoder allocates.

`mesh_from_file` reads an OBJ, PLY, GLB or glTF upload with trimesh, exactly as the service always
has (`process=False, force="mesh", maintain_order=True`), but only after the file's own declarations
have been checked against the request limits and against the bytes actually sent. Every size
trimesh would allocate by is bounded first:

* GLB / glTF: the GLB header and chunk lengths must fit the data; the JSON is bounded (a GLB's JSON
  chunk by `MAX_JSON_BYTES`, every glTF JSON by `MAX_JSON_TOKENS` structural characters; nesting
  that json.loads cannot take is a 400). Every buffer's `byteLength` must lie within the bytes
  present (the GLB BIN chunk or a base64 `data:` URI; external file URIs are refused), every
  bufferView within its buffer, every accessor's `byteOffset + (count - 1) * stride + element size`
  within its bufferView. Sparse accessors, Draco, meshopt and GPU instancing are refused, and so are
  primitives that are not triangle lists. The scene is walked the way trimesh walks it, so the
  vertices and faces of every placed mesh instance (primitives concatenated, as trimesh does) are
  summed against `max_vertices` / `max_faces`, the instances and node references against
  `MAX_GLTF_INSTANCES` / `MAX_GLTF_NODE_REFS`, the nesting against `MAX_GLTF_DEPTH`, and the sum
  of each instance's depth cubed against `MAX_GLTF_PATH_COST` (trimesh's transform lookup costs
  about depth^3 per instance: 200 nested nodes took it 20 s). trimesh then gets a rewritten GLB
  holding only the scene graph and the POSITION / index data of the placed meshes, copied
  densely: no images, textures, samplers or materials, so no texture is ever decoded. (One
  deliberate difference: a node carrying both the file's first camera and a mesh keeps its mesh.)
* OBJ: after trimesh's own normalisation (strip, CRLF, backslash continuations) the `v`, `vt`,
  `vn` lines, the face lines and the triangles they make (k indices make k - 2) are counted at the
  bytes level, and every face index must be at most the largest of those line counts (trimesh's
  `maintain_order` path allocates by the largest index).
* PLY: the header is parsed like trimesh parses it; `element vertex N` and `element face M` are
  checked against the limits, other elements against `max_vertices + max_faces`; binary data must
  be at least as long as the records declared (list lengths read from the first record, as trimesh
  does), and the face records' triangles (M * (k - 2)) are bounded; ASCII data may not have many
  more lines than records (trimesh parses every line), and its face rows' triangles are counted.

`gltf_tree_and_reader` gives other readers of GLB / glTF uploads (a skinned body) the same checks
of the container, buffers, bufferViews and accessors, and the accessors' data as numpy arrays.

Errors (all naming the field "mesh"): `LimitExceeded` (413) when a declared count exceeds a limit,
`MalformedInput` (400) for declarations inconsistent with each other or with the data, and for
anything trimesh cannot read, `InvalidInput` (422) for a supported file using a feature drape does
not take (file suffix, external URIs, sparse or compressed geometry, non-triangle primitives) and
for a file with no triangles.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import re
import struct
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, NoReturn, cast

import numpy as np

from drape.geometry.mesh_io import absolute_indices, without_materials
from drape.service.errors import DrapeError, InvalidInput, LimitExceeded, MalformedInput, NotFound
from drape.service.notices import warn

MESH_FILE_TYPES = {".obj": "obj", ".ply": "ply", ".glb": "glb", ".gltf": "gltf"}
FIELD = "mesh"

MAX_JSON_BYTES = 16 * 2**20  # a GLB's JSON chunk (a .gltf file is bounded by the body limit)
MAX_JSON_TOKENS = 200_000  # the characters {}[],: in a glTF JSON (bounds its Python objects)
MAX_GLTF_INSTANCES = 4096  # mesh primitives placed in the scene: each becomes a trimesh object
MAX_GLTF_NODE_REFS = 20_000  # parent -> child node references trimesh walks
MAX_GLTF_DEPTH = 64  # levels of nested nodes
MAX_GLTF_PATH_COST = 2**22  # sum over placed instances of depth^3 (trimesh's transform lookups)
MAX_GLB_CHUNKS = 64
MAX_PLY_HEADER_BYTES = 64 * 2**10
PLY_LINE_SLACK = 64  # ASCII PLY lines allowed beyond the declared records (blank trailing lines)


def mesh_from_file(data: bytes, filename: str, *, max_vertices: int,
                   max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """Read an uploaded OBJ/PLY/GLB/glTF mesh (by its file name's suffix) into plain arrays.

    -> (vertices (N, 3) float, faces (F, 3) int) as trimesh reads them (other shapes, from broken
    files, are a MalformedInput); see the module docstring for what is checked before trimesh sees
    the file, and which domain error answers what.
    """
    read = mesh_file(data, filename, max_vertices=max_vertices, max_faces=max_faces, uv=False)
    return read.vertices, read.faces


@dataclass(frozen=True)
class MeshFile:
    """An uploaded mesh as read: vertices (N, 3), faces (F, 3); uv_corners (F, 3, 2) float32, the texture
    coordinates of the faces' corners (OBJ's convention), or None where the file has none (or they do not map
    onto the faces read): an OBJ's `vt` (drape.geometry.mesh_io.obj_uv_corners), a GLB's TEXCOORD_0; parts: a
    GLB's placed meshes as named vertex ranges [{"name", "start", "stop"}] (an OBJ's: drape.geometry.mesh_io.
    obj_parts), or None."""

    vertices: np.ndarray
    faces: np.ndarray
    uv_corners: np.ndarray | None = None
    parts: list[dict] | None = None


def mesh_file(data: bytes, filename: str, *, max_vertices: int, max_faces: int, uv: bool = True) -> MeshFile:
    """`mesh_from_file` with the file's texture coordinates (uv False: not read, for a caller that does not use
    them) and, for a GLB/glTF, its parts (MeshFile)."""
    suffix = "." + filename.rsplit(".", 1)[-1].lower() if "." in filename else ""
    if suffix not in MESH_FILE_TYPES:
        raise InvalidInput(f"file name must end in one of {sorted(MESH_FILE_TYPES)}, "
                           f"got {filename!r}", FIELD)
    file_type = MESH_FILE_TYPES[suffix]
    try:
        if suffix == ".glb":
            data, file_type = _checked_glb(data, max_vertices, max_faces), "glb"
        elif suffix == ".gltf":
            data, file_type = _checked_gltf(data, max_vertices, max_faces), "glb"
        elif suffix == ".obj":
            _check_line_breaks(data)
            data = without_materials(data)
            _check_obj(data, max_vertices, max_faces)
            data = absolute_indices(data)  # after the counts are bounded (it rewrites the face lines)
        else:
            _check_ply(data, max_vertices, max_faces)
    except DrapeError:
        raise
    except Exception as exc:  # a check tripping on a broken file reads as the broken file
        raise MalformedInput(f"could not read the {suffix} file ({type(exc).__name__}: {exc})",
                             FIELD) from exc
    return _load(data, file_type, suffix, max_uvs=max_vertices + 3 * max_faces if uv else 0)


# what str.splitlines (trimesh's OBJ reader) breaks lines at besides LF and CR: a `v` line holding 10 million
# vertices separated by vertical tabs counted as one vertex here and built 4 GB there
_OTHER_LINE_BREAKS = re.compile(rb"[\x0b\x0c\x1c\x1d\x1e]|\xc2\x85|\xe2\x80[\xa8\xa9]")


def _check_line_breaks(data: bytes) -> None:
    found = _OTHER_LINE_BREAKS.search(data)
    if found:
        _bad(f"the OBJ holds a line break other than LF or CRLF ({found.group(0)!r} at byte {found.start()}): "
             "its lines would be counted otherwise than read")


def _load(data: bytes, file_type: str, suffix: str, max_uvs: int) -> MeshFile:
    """The checked file read by trimesh -> MeshFile; max_uvs: texture coordinates read at most (0: none)."""
    from drape.geometry.mesh_io import obj_uv_corners, read_trimesh, read_trimesh_parts

    parts = None
    try:
        if file_type == "glb":  # the checked copy: triangle meshes only, each placed one a part
            mesh, parts = read_trimesh_parts(io.BytesIO(data), file_type)
        else:
            mesh = read_trimesh(io.BytesIO(data), file_type=file_type)
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        uv = getattr(mesh.visual, "uv", None)  # a GLB's TEXCOORD_0 (trimesh turns it to OBJ's convention)
    except Exception as exc:  # trimesh raises many kinds on broken files
        raise MalformedInput(f"could not read the {suffix} file ({type(exc).__name__}: {exc})",
                             FIELD) from exc
    if len(v) == 0 or len(f) == 0:
        raise InvalidInput("the file holds no triangles", FIELD)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise MalformedInput(f"the {suffix} file reads as vertices {v.shape} and faces {f.shape}, "
                             "not (N, 3) and (F, 3)", FIELD)
    corners = None
    if not max_uvs:
        return MeshFile(v, f, None, parts)
    if suffix == ".obj":
        corners = obj_uv_corners(data, f, max_uvs)
        if corners is None and re.search(rb"(?m)^[ \t]*vt[ \t]", data):
            warn(f"{FIELD}: the file's texture coordinates do not map onto its faces (a face without them, an "
                 "index out of range, a value that is not a finite number): the answer has none")
    elif uv is not None and np.shape(uv) == (len(v), 2) and f.min() >= 0 and f.max() < len(v):
        corners = np.asarray(uv, np.float32)[f]
        corners = corners if np.isfinite(corners).all() else None
    if corners is None and file_type == "glb" and b"TEXCOORD_0" in data:  # kept for some primitives, not all
        warn(f"{FIELD}: texture coordinates are on some of the file's meshes only (or not finite): the answer has "
             "none")
    return MeshFile(v, f, corners, parts)


def _bad(detail: str) -> NoReturn:
    raise MalformedInput(detail, FIELD)


def _over(what: str, count: int, limit: int, at_least: bool = False) -> NoReturn:
    declares = "declares at least" if at_least else "declares"
    raise LimitExceeded(f"the file {declares} {count} {what}, over the limit of {limit}", FIELD)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


# ---------------------------------------------------------------------------------------- glTF

_GLB_JSON, _GLB_BIN = 0x4E4F534A, 0x004E4942
_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_TYPE_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_INDEX_COMPONENTS = (5121, 5123, 5125)
_REFUSED_EXTENSIONS = {
    "KHR_draco_mesh_compression": "Draco-compressed geometry",
    "EXT_meshopt_compression": "meshopt-compressed geometry",
    "EXT_mesh_gpu_instancing": "GPU instancing",
}
_NODE_TRANSFORMS = {"matrix": 16, "translation": 3, "rotation": 4, "scale": 3}


@dataclass(frozen=True)
class _View:
    buffer: int
    offset: int
    length: int
    stride: int | None


@dataclass(frozen=True)
class _Accessor:
    view: int | None
    offset: int
    count: int
    component: int
    kind: str
    element: int  # bytes of one element
    stride: int  # bytes from one element to the next


def _checked_glb(data: bytes, max_vertices: int, max_faces: int) -> bytes:
    """A GLB upload -> the rewritten GLB handed to trimesh (geometry only)."""
    json_chunk, bin_chunk = _glb_chunks(data)
    tree = _parse_json(bytes(json_chunk))
    return _rewrite(tree, _buffers(tree, bin_chunk, glb=True), max_vertices, max_faces)


def _glb_chunks(data: bytes) -> tuple[memoryview, memoryview | None]:
    """A GLB's header and chunks checked against the bytes sent -> (JSON chunk, BIN chunk or None)."""
    if len(data) < 20:
        _bad(f"{len(data)} bytes are too few for a GLB (a 12-byte header and a chunk)")
    magic, version, length = struct.unpack_from("<4sII", data)
    if magic != b"glTF":
        _bad("not a GLB file (the first 4 bytes are not 'glTF')")
    if version != 2:
        _bad(f"GLB version {version}: only glTF 2 is supported")
    if not 20 <= length <= len(data):
        _bad(f"the GLB header declares {length} bytes but {len(data)} were sent")
    view = memoryview(data)[:length]
    pos, chunks = 12, 0
    json_chunk: memoryview | None = None
    bin_chunk: memoryview | None = None
    while pos + 8 <= length and (json_chunk is None or bin_chunk is None):
        chunk_length, chunk_type = struct.unpack_from("<II", data, pos)
        pos += 8
        if chunk_length > length - pos:
            _bad(f"a GLB chunk declares {chunk_length} bytes but only {length - pos} remain")
        chunk = view[pos:pos + chunk_length]
        pos += chunk_length
        chunks += 1
        if chunks > MAX_GLB_CHUNKS:
            _bad(f"more than {MAX_GLB_CHUNKS} GLB chunks")
        if json_chunk is None:
            if chunk_type != _GLB_JSON:
                _bad("the first GLB chunk is not the JSON chunk")
            json_chunk = chunk
        elif chunk_type == _GLB_BIN:
            bin_chunk = chunk
    if json_chunk is None:
        _bad("the GLB has no JSON chunk")
    if len(json_chunk) > MAX_JSON_BYTES:
        raise LimitExceeded(f"the GLB's JSON chunk has {len(json_chunk)} bytes, over the limit of "
                            f"{MAX_JSON_BYTES}", FIELD)
    return json_chunk, bin_chunk


def _checked_gltf(data: bytes, max_vertices: int, max_faces: int) -> bytes:
    """A .gltf upload (JSON, buffers as base64 data: URIs) -> the rewritten GLB."""
    tree = _parse_json(data)
    return _rewrite(tree, _buffers(tree, None, glb=False), max_vertices, max_faces)


def _parse_json(raw: bytes) -> dict[str, Any]:
    tokens = sum(raw.count(c) for c in (b"{", b"}", b"[", b"]", b",", b":"))
    if tokens > MAX_JSON_TOKENS:
        raise LimitExceeded(f"the glTF JSON has {tokens} structural characters, over the limit of "
                            f"{MAX_JSON_TOKENS}", FIELD)
    try:
        tree = json.loads(raw.decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:  # RecursionError: deep nesting
        _bad(f"the glTF JSON is unreadable ({type(exc).__name__}: {str(exc)[:200]})")
    if not isinstance(tree, dict):
        _bad("the glTF JSON is not an object")
    asset = tree.get("asset")
    version = asset.get("version", "2.0") if isinstance(asset, dict) else "2.0"
    if not isinstance(version, str) or version.split(".", 1)[0] != "2":
        _bad(f"glTF version {_short(version)}: only glTF 2 is supported")
    return tree


def _items(tree: dict[str, Any], key: str) -> list[dict[str, Any]]:
    value = tree.get(key, [])
    if not isinstance(value, list) or not all(isinstance(x, dict) for x in value):
        _bad(f"glTF '{key}' must be a list of objects")
    return value


def _int(obj: dict[str, Any], key: str, where: str, default: int | None = None,
         minimum: int = 0) -> int:
    value = obj.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        _bad(f"{where}.{key} must be an integer >= {minimum}, got {_short(value)}")
    return value


def _index(value: Any, size: int, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < size:
        _bad(f"{where} must be an index below {size}, got {_short(value)}")
    return value


def _buffers(tree: dict[str, Any], bin_chunk: memoryview | None, glb: bool) -> list[memoryview]:
    """Each buffer's bytes, checked to hold its declared byteLength."""
    out = []
    for i, b in enumerate(_items(tree, "buffers")):
        declared = _int(b, "byteLength", f"buffers[{i}]")
        uri = b.get("uri")
        if uri is None:
            if not glb or i != 0:
                _bad(f"buffers[{i}] has no uri (only a GLB's first buffer may use its BIN chunk)")
            if bin_chunk is None:
                _bad("buffers[0] refers to the GLB's BIN chunk, which is absent")
            present = bin_chunk
        elif not isinstance(uri, str):
            _bad(f"buffers[{i}].uri must be a string")
        elif not uri.startswith("data:"):
            raise InvalidInput(f"buffers[{i}] refers to the external file {_short(uri)}: send a "
                               "GLB or a .gltf with its buffers embedded as base64 data: URIs",
                               FIELD)
        else:
            head, sep, payload = uri.partition(",")
            if not sep or not head.endswith(";base64"):
                raise InvalidInput(f"buffers[{i}]: only base64 data: URIs are supported", FIELD)
            try:
                # validate: b64decode otherwise drops what is not base64 and reports the bytes left as missing
                present = memoryview(base64.b64decode("".join(payload.split()), validate=True))
            except (binascii.Error, ValueError) as exc:
                _bad(f"buffers[{i}]: the base64 data is unreadable ({exc})")
        if declared > len(present):
            _bad(f"buffers[{i}] declares {declared} bytes but only {len(present)} are present")
        out.append(present[:declared])
    return out


def _views(tree: dict[str, Any], buffers: list[memoryview]) -> list[_View]:
    out = []
    for i, v in enumerate(_items(tree, "bufferViews")):
        where = f"bufferViews[{i}]"
        buffer = _index(v.get("buffer"), len(buffers), f"{where}.buffer")
        offset = _int(v, "byteOffset", where, 0)
        length = _int(v, "byteLength", where, minimum=1)
        stride = v.get("byteStride")
        if stride is not None:
            stride = _int(v, "byteStride", where, minimum=4)
            if stride > 252:
                _bad(f"{where}.byteStride must be at most 252, got {stride}")
        if offset + length > len(buffers[buffer]):
            _bad(f"{where} (bytes {offset}..{offset + length}) lies beyond buffers[{buffer}] "
                 f"({len(buffers[buffer])} bytes)")
        extensions = v.get("extensions")
        if isinstance(extensions, dict) and "EXT_meshopt_compression" in extensions:
            raise InvalidInput("meshopt-compressed buffer views are not supported", FIELD)
        out.append(_View(buffer, offset, length, stride))
    return out


def _accessors(tree: dict[str, Any], views: list[_View]) -> list[_Accessor]:
    out = []
    for i, a in enumerate(_items(tree, "accessors")):
        where = f"accessors[{i}]"
        if "sparse" in a:
            raise InvalidInput(f"{where} is sparse; sparse accessors are not supported", FIELD)
        component, kind = a.get("componentType"), a.get("type")
        if component not in _COMPONENT_BYTES or kind not in _TYPE_WIDTH:
            _bad(f"{where} has an unknown componentType {_short(component)} or type {_short(kind)}")
        count = _int(a, "count", where, minimum=1)
        element = _COMPONENT_BYTES[component] * _TYPE_WIDTH[kind]
        view_index = a.get("bufferView")
        offset = _int(a, "byteOffset", where, 0)
        stride = element
        if view_index is not None:
            view = views[_index(view_index, len(views), f"{where}.bufferView")]
            stride = view.stride or element
            if stride < element:
                _bad(f"{where}: its bufferView's byteStride {stride} is below its element size "
                     f"{element}")
            end = offset + (count - 1) * stride + element
            if end > view.length:
                _bad(f"{where} ({count} elements, bytes {offset}..{end}) lies beyond bufferViews"
                     f"[{view_index}] ({view.length} bytes)")
        out.append(_Accessor(view_index, offset, count, component, kind, element, stride))
    return out


@dataclass(frozen=True)
class _Mesh:
    vertices: int
    faces: int
    primitives: list[tuple[int, int | None, int | None]]  # (POSITION, indices or None, TEXCOORD_0 or None) accessors


def _meshes(tree: dict[str, Any], accessors: list[_Accessor]) -> list[_Mesh]:
    def data_accessor(index: Any, where: str) -> _Accessor:
        acc = accessors[_index(index, len(accessors), where)]
        if acc.view is None:
            _bad(f"{where}: accessors[{index}] has no bufferView, so no data behind its "
                 f"{acc.count} elements")
        return acc

    out = []
    for i, m in enumerate(_items(tree, "meshes")):
        primitives = m.get("primitives", [])
        if not isinstance(primitives, list) or not all(isinstance(p, dict) for p in primitives):
            _bad(f"meshes[{i}].primitives must be a list of objects")
        vertices = faces = 0
        prims: list[tuple[int, int | None, int | None]] = []
        for j, p in enumerate(primitives):
            where = f"meshes[{i}].primitives[{j}]"
            extensions = p.get("extensions")
            if isinstance(extensions, dict):
                for name in extensions:
                    if name in _REFUSED_EXTENSIONS:
                        raise InvalidInput(f"{where} uses {name}: {_REFUSED_EXTENSIONS[name]} is "
                                           "not supported", FIELD)
            mode = p.get("mode", 4)
            if mode != 4 or isinstance(mode, bool):
                raise InvalidInput(f"{where} has mode {_short(mode)}: only triangle lists (mode 4) "
                                   "are supported", FIELD)
            attributes = p.get("attributes")
            if not isinstance(attributes, dict) or "POSITION" not in attributes:
                _bad(f"{where} has no POSITION attribute")
            position = data_accessor(attributes["POSITION"], f"{where}.attributes.POSITION")
            if position.kind != "VEC3" or position.component != 5126:
                raise InvalidInput(f"{where}: POSITION must be float VEC3 (got componentType "
                                   f"{position.component}, type {position.kind})", FIELD)
            corners = position.count
            indices = p.get("indices")
            if indices is not None:
                index_acc = data_accessor(indices, f"{where}.indices")
                if index_acc.kind != "SCALAR" or index_acc.component not in _INDEX_COMPONENTS:
                    _bad(f"{where}.indices must be unsigned integer scalars")
                corners = index_acc.count
            if corners % 3:
                _bad(f"{where} has {corners} triangle corners, not a multiple of 3")
            vertices += position.count
            faces += corners // 3
            texcoord = attributes.get("TEXCOORD_0")  # kept when float VEC2, one per vertex (else left out)
            if texcoord is not None:
                tex_acc = accessors[_index(texcoord, len(accessors), f"{where}.attributes.TEXCOORD_0")]
                if (tex_acc.view is None or tex_acc.kind != "VEC2" or tex_acc.component != 5126
                        or tex_acc.count != position.count):
                    warn(f"{FIELD}: {where}.attributes.TEXCOORD_0 is not float VEC2, one per vertex: left out "
                         "(the answer has no texture coordinates for it)")
                    texcoord = None
            prims.append((attributes["POSITION"], indices, texcoord))
        out.append(_Mesh(vertices, faces, prims))
    return out


def _placed_meshes(tree: dict[str, Any], meshes: list[_Mesh], max_vertices: int,
                   max_faces: int) -> tuple[list[int], set[int]]:
    """Walk the scene as trimesh does -> (root nodes, meshes placed); refuse over the limits.

    trimesh pops (parent, child) edges from the right of a queue, once per distinct edge; a node
    whose mesh has one primitive becomes one instance (its frame), a node whose mesh has several
    becomes one instance per primitive per edge reaching it (each a frame below the node's).
    Placing an instance d frames below the base costs trimesh's transform lookup (numpy's
    multi_dot chain ordering) about d^3 steps, so the sum of d^3 is bounded too.
    """
    nodes = _items(tree, "nodes")
    if "scenes" not in tree:
        return [], set()
    scenes = _items(tree, "scenes")
    scene = scenes[_index(tree.get("scene", 0), len(scenes), "scene")]
    roots = scene.get("nodes", [])
    if not isinstance(roots, list):
        _bad("scenes[].nodes must be a list")
    queue = [(-1, _index(r, len(nodes), "scenes[].nodes[]"), 1) for r in roots]
    pushed = len(queue)
    consumed: set[tuple[int, int]] = set()
    single: dict[int, int] = {}  # node placing a one-primitive mesh -> its deepest depth
    used: set[int] = set()
    vertices = faces = instances = path_cost = 0
    while queue:
        a, b, depth = queue.pop()
        if (a, b) in consumed:
            continue
        consumed.add((a, b))
        if depth > MAX_GLTF_DEPTH:
            _over("levels of nested nodes in the scene", depth, MAX_GLTF_DEPTH, at_least=True)
        node = nodes[b]
        children = node.get("children", [])
        if not isinstance(children, list):
            _bad(f"nodes[{b}].children must be a list")
        pushed += len(children)
        if pushed > MAX_GLTF_NODE_REFS:
            _over("node references in the scene", pushed, MAX_GLTF_NODE_REFS)
        queue.extend((b, _index(c, len(nodes), f"nodes[{b}].children[]"), depth + 1)
                     for c in children)
        if "mesh" not in node:
            continue
        m = _index(node["mesh"], len(meshes), f"nodes[{b}].mesh")
        mesh = meshes[m]
        if len(mesh.primitives) == 1:
            seen = b in single
            single[b] = max(single.get(b, 0), depth)
            if seen:
                continue
        else:
            path_cost += len(mesh.primitives) * (depth + 1) ** 3
        used.add(m)
        vertices += mesh.vertices
        faces += mesh.faces
        instances += len(mesh.primitives)
        if vertices > max_vertices:
            _over("vertices in its placed meshes", vertices, max_vertices, at_least=True)
        if faces > max_faces:
            _over("triangles in its placed meshes", faces, max_faces, at_least=True)
        if instances > MAX_GLTF_INSTANCES:
            _over("placed mesh primitives", instances, MAX_GLTF_INSTANCES, at_least=True)
    path_cost += sum(d**3 for d in single.values())
    if path_cost > MAX_GLTF_PATH_COST:
        _over("(node depth)^3 summed over its placed meshes", path_cost, MAX_GLTF_PATH_COST)
    return roots, used


def _dense(acc: _Accessor, views: list[_View], buffers: list[memoryview]) -> bytes:
    """The accessor's elements, tightly packed (the bounds were checked in `_accessors`)."""
    assert acc.view is not None
    view = views[acc.view]
    start = view.offset + acc.offset
    buf = buffers[view.buffer]
    if acc.stride == acc.element:
        return bytes(buf[start:start + acc.count * acc.element])
    raw = np.frombuffer(buf, np.uint8, count=(acc.count - 1) * acc.stride + acc.element,
                        offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, (acc.count, acc.element), (acc.stride, 1))
    return rows.tobytes()


_DTYPES = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}


def gltf_tree_and_reader(data: bytes, suffix: str, *, field: str = FIELD
                         ) -> tuple[dict[str, Any], Callable[[int], np.ndarray]]:
    """A GLB (suffix ".glb") or .gltf (".gltf", buffers embedded) upload -> (JSON tree, read_accessor).

    The structure is checked as `mesh_from_file` checks it (GLB header and chunks, the JSON's bounds,
    every buffer, bufferView and accessor within the bytes present, refused extensions); nothing
    else of the tree is (its meshes, nodes and skins are the caller's to check). read_accessor(i)
    -> accessor i's elements as a new array of its component type (int8 .. uint32, float32;
    `normalized` not applied): (count,) for SCALAR, (count, n) for VECn, (count, n, n) for MATn
    indexed [element, row, column]. An index out of range, an accessor with no bufferView, or a
    MAT2 / MAT3 of 1- or 2-byte components is refused. Errors are those of `mesh_from_file`,
    naming `field`.
    """
    with _reported_as(field, suffix):
        if suffix == ".glb":
            json_chunk, bin_chunk = _glb_chunks(data)
            tree = _parse_json(bytes(json_chunk))
            buffers = _buffers(tree, bin_chunk, glb=True)
        elif suffix == ".gltf":
            tree = _parse_json(data)
            buffers = _buffers(tree, None, glb=False)
        else:
            raise InvalidInput(f"the file must be a .glb or a .gltf, got {_short(suffix)}", FIELD)
        _check_required_extensions(tree)
        views = _views(tree, buffers)
        accessors = _accessors(tree, views)

    def read_accessor(index: int) -> np.ndarray:
        with _reported_as(field, suffix):
            acc = accessors[_index(index, len(accessors), "an accessor index")]
            width = _TYPE_WIDTH[acc.kind]
            if acc.view is None:
                _bad(f"accessors[{index}] has no bufferView, so no data behind its {acc.count} "
                     "elements")
            if acc.kind in ("MAT2", "MAT3") and _COMPONENT_BYTES[acc.component] < 4:
                raise InvalidInput(f"accessors[{index}]: {acc.kind} of {acc.component} components "
                                   "(padded columns) is not supported", FIELD)
            values = np.frombuffer(bytearray(_dense(acc, views, buffers)), _DTYPES[acc.component])
            if acc.kind == "SCALAR":
                return values
            if acc.kind.startswith("VEC"):
                return values.reshape(acc.count, width)
            n = int(acc.kind[3])
            return np.ascontiguousarray(values.reshape(acc.count, n, n).transpose(0, 2, 1))

    return tree, read_accessor


@contextmanager
def _reported_as(field: str, suffix: str) -> Iterator[None]:
    """Domain errors raised inside re-raised naming `field`; anything else as a broken file."""
    try:
        yield
    except DrapeError as exc:
        if exc.field == field:
            raise
        raise type(exc)(str(exc), field) from exc
    except Exception as exc:  # a check tripping on a broken file reads as the broken file
        raise MalformedInput(f"could not read the {suffix} file ({type(exc).__name__}: "
                             f"{str(exc)[:200]})", field) from exc


def _node(node: dict[str, Any], index: int, mesh_map: dict[int, int]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(node.get("name"), str):
        out["name"] = node["name"]
    children = node.get("children")
    if isinstance(children, list) and all(isinstance(c, int) for c in children):
        out["children"] = children  # in range where reached: checked by the walk
    mesh = node.get("mesh")
    if isinstance(mesh, int) and not isinstance(mesh, bool) and mesh in mesh_map:
        out["mesh"] = mesh_map[mesh]
    for key, size in _NODE_TRANSFORMS.items():
        if key in node:
            value = node[key]
            numbers = isinstance(value, list) and all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in value)
            if not numbers or len(value) != size:
                _bad(f"nodes[{index}].{key} must be a list of {size} numbers")
            out[key] = value
    return out


def _check_required_extensions(tree: dict[str, Any]) -> None:
    required = tree.get("extensionsRequired", [])
    if isinstance(required, list):
        for name in required:
            if name in _REFUSED_EXTENSIONS:
                raise InvalidInput(f"the file requires {name}: {_REFUSED_EXTENSIONS[name]} is not "
                                   "supported", FIELD)


def _rewrite(tree: dict[str, Any], buffers: list[memoryview], max_vertices: int,
             max_faces: int) -> bytes:
    """Check the declarations, then build a GLB of the placed geometry alone (and float texture coordinates)."""
    _check_required_extensions(tree)
    views = _views(tree, buffers)
    accessors = _accessors(tree, views)
    meshes = _meshes(tree, accessors)
    roots, used = _placed_meshes(tree, meshes, max_vertices, max_faces)
    if not used:
        raise InvalidInput("the file holds no triangles (no mesh is placed in its scene)", FIELD)
    mesh_map = {m: k for k, m in enumerate(sorted(used))}
    acc_map: dict[int, int] = {}
    new_accessors: list[dict[str, Any]] = []
    new_views: list[dict[str, Any]] = []
    blob = bytearray()

    def copy(index: int) -> int:
        if index not in acc_map:
            acc = accessors[index]
            data = _dense(acc, views, buffers)
            blob.extend(bytes(-len(blob) % 4))
            new_views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
            blob.extend(data)
            acc_map[index] = len(new_accessors)
            new_accessors.append({"bufferView": len(new_views) - 1, "componentType": acc.component,
                                  "type": acc.kind, "count": acc.count})
        return acc_map[index]

    new_meshes = []
    for m in sorted(used):
        prims = []
        for position, indices, texcoord in meshes[m].primitives:
            prim: dict[str, Any] = {"attributes": {"POSITION": copy(position)}, "mode": 4}
            if texcoord is not None:  # the garment's texture coordinates, for the rig's GLB (trimesh reads a
                prim["attributes"]["TEXCOORD_0"] = copy(texcoord)  # primitive's UVs only with a material: a plain one)
                prim["material"] = 0
            if indices is not None:
                prim["indices"] = copy(indices)
            prims.append(prim)
        name = tree["meshes"][m].get("name")
        named = {"name": name} if isinstance(name, str) else {}
        new_meshes.append({"primitives": prims, **named})
    nodes = [_node(n, i, mesh_map) for i, n in enumerate(_items(tree, "nodes"))]
    blob.extend(bytes(-len(blob) % 4))
    header = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": roots}], "nodes": nodes,
              "meshes": new_meshes, "accessors": new_accessors, "bufferViews": new_views,
              "buffers": [{"byteLength": len(blob)}], "materials": [{"name": "plain"}]}
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return b"".join([struct.pack("<4sII", b"glTF", 2, total),
                     struct.pack("<II", len(text), _GLB_JSON), text,
                     struct.pack("<II", len(blob), _GLB_BIN), bytes(blob)])


# ----------------------------------------------------------------------------------------- OBJ

_DIGIT = np.zeros(256, bool)
_DIGIT[48:58] = True
_INDEX_BATCH = 4 * 2**20  # bytes of face lines gathered for one index check
_INDEX_WINDOW = 2**20  # bytes of them scanned at a time


def _check_obj(data: bytes, max_vertices: int, max_faces: int) -> None:
    """Count what trimesh's OBJ reader will build, at the bytes level, before it runs."""
    # trimesh reads text.strip() with CRLF -> LF and backslash continuations joined; the strip
    # only moves the first line's start, so it is not copied
    text = data.replace(b"\r\n", b"\n") if b"\r\n" in data else data
    text = text.replace(b"\\\n", b"") if b"\\\n" in text else text
    start = cast(re.Match, re.match(rb"\s*", text)).end()

    def lines_starting(prefix: bytes) -> int:
        return text.count(b"\n" + prefix, start) + text.startswith(prefix, start)

    nv = lines_starting(b"v ")
    if nv > max_vertices:
        _over("vertices ('v' lines)", nv, max_vertices)
    corner_limit = max_vertices + 3 * max_faces  # UVs and normals belong to face corners
    nvt, nvn = lines_starting(b"vt "), lines_starting(b"vn ")
    for key, n in (("vt", nvt), ("vn", nvn)):
        if n > corner_limit:
            _over(f"'{key}' lines", n, corner_limit)
    face_lines = lines_starting(b"f")
    if face_lines > max_faces:
        _over("face lines (each makes at least one triangle)", face_lines, max_faces)
    # trimesh's maintain_order path allocates (3, largest index + 1) arrays: bound every index by
    # the most lines of a kind an index can refer to (no vertices: trimesh reads no geometry)
    bound = max(nv, nvt, nvn)
    triangles = 0
    batch = bytearray()
    pos: int | None = start - 1  # the newline before a face line (virtual for the first line)
    if not text.startswith(b"f", start):
        found = text.find(b"\nf", start)
        pos = found if found >= 0 else None
    while pos is not None:
        end = text.find(b"\n", pos + 1)
        end = len(text) if end < 0 else end
        line = text[pos + 2:end]
        found = text.find(b"\nf", end)
        pos = found if found >= 0 else None
        triangles += max(len(line.split(None, max_faces - triangles + 3)) - 2, 0)
        if triangles > max_faces:
            _over("triangles (a face with k indices makes k - 2)", triangles, max_faces,
                  at_least=True)
        if bound:
            batch += line
            batch += b"\n"
            if len(batch) >= _INDEX_BATCH:
                _check_indices(batch, bound)
                batch.clear()
    if batch:
        _check_indices(batch, bound)


def _too_many_digits(digits: int, bound: int) -> NoReturn:
    _bad(f"a face index has more than {digits} digit{'s' * (digits > 1)}, beyond the file's "
         f"{bound} vertices")


def _check_indices(text: bytes | bytearray, bound: int) -> None:
    """Refuse a number (digit run) in text above bound, in windows (no run spans two)."""
    digits = len(str(bound))
    scale = 10 ** np.arange(digits - 1, -1, -1, dtype=np.int64)
    pos = 0
    while pos < len(text):
        arr = np.frombuffer(text, np.uint8, count=min(_INDEX_WINDOW, len(text) - pos), offset=pos)
        is_digit = _DIGIT[arr]
        if pos + len(arr) < len(text):  # end the window after its last non-digit
            tail = int(np.argmin(is_digit[::-1]))
            if is_digit[-1 - tail]:
                _too_many_digits(digits, bound)
            arr, is_digit = arr[:len(arr) - tail], is_digit[:len(arr) - tail]
        pos += len(arr)
        edges = np.diff(np.concatenate(([False], is_digit, [False])).view(np.int8))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        lengths = ends - starts
        if not len(lengths):
            continue
        if lengths.max() > digits:
            _too_many_digits(digits, bound)
        longest = starts[lengths == digits]
        if len(longest):
            values = np.zeros(len(longest), np.int64)
            for j in range(digits):
                values += (arr[longest + j].astype(np.int64) - 48) * scale[j]
            if values.max() > bound:
                at = int(longest[int(np.argmax(values))])
                negative = at > 0 and arr[at - 1] == ord("-")  # OBJ's relative index: -k is k back from the end
                _bad(f"a face refers to index {'-' if negative else ''}{values.max()}, beyond the file's {bound} "
                     "vertices")


# ----------------------------------------------------------------------------------------- PLY

_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "int8": "i1",
              "int16": "i2", "int32": "i4", "int64": "i8", "uint": "u4", "uint8": "u1",
              "uint16": "u2", "uint32": "u4", "uint64": "u8", "float": "f4", "float16": "f2",
              "float32": "f4", "float64": "f8", "double": "f8"}
_PLY_INDEX_NAMES = ("vertex_index", "vertex_indices")
_LINE_BREAKS = (b"\n", b"\r", b"\x0b", b"\x0c", b"\x1c", b"\x1d", b"\x1e", b"\xc2\x85",
                b"\xe2\x80\xa8", b"\xe2\x80\xa9")  # what str.splitlines splits on, in UTF-8


@dataclass
class _PlyProperty:
    name: str
    dtype: np.dtype  # the value, or the list's items
    count_dtype: np.dtype | None  # the list length; None for a scalar


@dataclass
class _PlyElement:
    name: str
    count: int
    properties: list[_PlyProperty]


def _ply_header(data: bytes) -> tuple[list[_PlyElement], bool, str, int]:
    """Parse the header the way trimesh does -> (elements, is_ascii, endian, data offset)."""
    f = io.BytesIO(data)

    def readline() -> bytes:
        line = f.readline(MAX_PLY_HEADER_BYTES + 1)
        if f.tell() > MAX_PLY_HEADER_BYTES:
            _bad(f"the PLY header is longer than {MAX_PLY_HEADER_BYTES} bytes or has no end_header")
        return line

    if b"ply" not in readline().lower():
        _bad("not a PLY file (no 'ply' on the first line)")
    encoding = readline().decode("utf-8").strip().lower()
    is_ascii = "ascii" in encoding
    endian = ">" if "big" in encoding else "<"
    elements: list[_PlyElement] = []
    while True:
        raw = readline()
        if not raw:
            _bad("the PLY header has no end_header")
        line = raw.decode("utf-8").strip().split()
        if "end_header" in line:
            return elements, is_ascii, endian, f.tell()
        if not line:
            _bad("the PLY header has an empty line")
        if "element" in line[0]:
            if len(line) != 3:
                _bad(f"bad PLY element line {_short(raw)}")
            try:
                count = int(line[2])
            except ValueError:
                _bad(f"bad PLY element count in {_short(raw)}")
            if count < 0:
                _bad(f"PLY element {line[1]!r} has a negative count")
            if any(e.name == line[1] for e in elements):
                _bad(f"PLY element {line[1]!r} is declared twice")
            elements.append(_PlyElement(line[1], count, []))
        elif "property" in line[0]:
            if not elements:
                _bad("a PLY property comes before any element")
            try:
                if len(line) == 3:
                    prop = _PlyProperty(line[2], np.dtype(endian + _PLY_TYPES[line[1]]), None)
                elif "list" in line[1] and len(line) == 5:
                    prop = _PlyProperty(line[4], np.dtype(endian + _PLY_TYPES[line[3]]),
                                        np.dtype(endian + _PLY_TYPES[line[2]]))
                else:
                    continue  # trimesh skips these too
            except KeyError as exc:
                _bad(f"unknown PLY type {exc}")
            elements[-1].properties.append(prop)


def _face_list(face: _PlyElement) -> int | None:
    """Position of the face element's vertex index list among its properties (None: none)."""
    lists = [i for i, p in enumerate(face.properties) if p.count_dtype is not None]
    named = [i for i in lists if face.properties[i].name in _PLY_INDEX_NAMES]
    return named[0] if named else (lists[0] if len(lists) == 1 else None)


def _check_ply(data: bytes, max_vertices: int, max_faces: int) -> None:
    """Bound a PLY's declared records by the limits and by the data present."""
    elements, is_ascii, endian, start = _ply_header(data)
    others = 0
    for e in elements:
        if e.name == "vertex" and e.count > max_vertices:
            _over("vertices", e.count, max_vertices)
        elif e.name == "face" and e.count > max_faces:
            _over("faces", e.count, max_faces)
        elif e.name not in ("vertex", "face"):
            others += e.count
    if others > max_vertices + max_faces:
        _over("records in elements other than vertex and face", others, max_vertices + max_faces)
    body = memoryview(data)[start:]
    if is_ascii:
        _check_ply_ascii(bytes(body), elements, max_faces)
    else:
        _check_ply_binary(body, elements, max_faces)


def _check_ply_binary(body: memoryview, elements: list[_PlyElement], max_faces: int) -> None:
    """Record sizes as trimesh computes them: list lengths from each element's first record."""
    pos = 0
    for e in elements:
        size = 0
        face_k = None
        face_list = _face_list(e) if e.name == "face" else None
        for i, p in enumerate(e.properties):
            if p.count_dtype is None:
                size += p.dtype.itemsize
                continue
            at = pos + size
            if at + p.count_dtype.itemsize > len(body):
                if e.count:
                    _bad(f"the PLY data ends inside the first {e.name!r} record")
                break
            k = int(np.frombuffer(body, p.count_dtype, count=1, offset=at)[0])
            if k < 0:
                _bad(f"the first {e.name!r} record has a negative list length")
            size += p.count_dtype.itemsize + k * p.dtype.itemsize
            if i == face_list:
                face_k = k
        if face_k is not None and e.count * max(face_k - 2, 1) > max_faces:
            _over(f"triangles ({e.count} faces of {face_k} corners)", e.count * max(face_k - 2, 1),
                  max_faces)
        need = e.count * size
        if need > len(body) - pos:
            _bad(f"the PLY header declares {e.count} {e.name!r} records of {size} bytes, but only "
                 f"{max(len(body) - pos, 0)} bytes of data are left")
        pos += need


def _check_ply_ascii(body: bytes, elements: list[_PlyElement], max_faces: int) -> None:
    """trimesh parses every line: bound the lines, then count the face rows' triangles."""
    records = sum(e.count for e in elements)
    breaks = sum(body.count(b) for b in _LINE_BREAKS) - body.count(b"\r\n")
    if breaks > records + PLY_LINE_SLACK:
        _bad(f"the PLY data has {breaks} lines for the {records} records its header declares")
    first = 0
    for e in elements:
        if e.name == "face":
            break
        first += e.count
    else:
        return
    lines = body.decode("utf-8").splitlines()[first:first + e.count]
    face_list = _face_list(e)
    k_first = None
    triangles = 0
    for row in lines:
        values = row.split(None, max_faces - triangles + 4)
        n = len(values) - 1
        corners = n
        if face_list == 0 and values:
            try:
                k = int(float(values[0]))
            except ValueError:
                k = n
            k_first = k if k_first is None else k_first
            corners = min(max(k, k_first), n)  # trimesh may slice every row by the first's length
        triangles += max(corners - 2, 0)
        if triangles > max_faces:
            _over("triangles (a face with k corners makes k - 2)", triangles, max_faces,
                  at_least=True)


# ---- motion files ----------------------------------------------------------------------------------

MOTION_FIELD = "motion_file"
MOTION_SOURCE_FACTOR = 8  # a motion file may hold this many times max_frames before resampling (240 -> 30 fps)


def motion_from_file(data: bytes, body_name: str, *, fps: float, up: str | None, max_frames: int,
                     max_decoded_bytes: int) -> tuple[np.ndarray, np.ndarray, float]:
    """An uploaded motion file (a CMU-named BVH or an AMASS-style npz; told apart by its first bytes) ->
    (poses (T, 24, 3), translation (T, 3), fps), imported as `drape motions import` does: retargeted onto
    the body preset, Y-up, the added CMU T-pose frame dropped, resampled to `fps`, feet on the floor.

    Bounded: the file is already within the body limit; its frames within MOTION_SOURCE_FACTOR x
    max_frames before any number is worked on, and within max_frames after resampling (413s); an npz's
    arrays within max_decoded_bytes. Anything else wrong is a 422; all name the field "motion_file". What the
    import warns of (an `up` the file contradicts, feet left off the floor) goes to the answer's warnings
    (drape.service.notices).
    """
    from drape.assets.body import load_body
    from drape.assets.motion import MotionFileError, MotionTooLong, import_motion

    try:
        body = load_body(body_name)
    except KeyError:  # checked by the caller, then DELETEd before this read it
        raise NotFound(f"unknown body {body_name[:60]!r}: it was deleted while the request was read", "body"
                       ) from None
    try:
        imported = import_motion(data, body, fps=fps, up=up, max_frames=max_frames,
                                 max_source_frames=MOTION_SOURCE_FACTOR * max_frames,
                                 max_decoded_bytes=max_decoded_bytes)
    except MotionTooLong as exc:
        raise LimitExceeded(str(exc), MOTION_FIELD) from exc
    except MotionFileError as exc:
        raise InvalidInput(str(exc), MOTION_FIELD) from exc
    for sentence in imported.warnings:  # done as asked, and said (the Drape-Warnings header)
        warn(f"{MOTION_FIELD}: {sentence}")
    m = imported.motion
    return m.poses.astype(np.float64), m.trans.astype(np.float64), m.fps
