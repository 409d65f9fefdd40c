"""Uploads are checked from their declarations before any decoder allocates (issue 24, part 1).

Hostile files are crafted small: each must be refused quickly with a domain error (or a
ValueError for npz) while tracemalloc sees almost nothing allocated; good files must read exactly
as `plain_read` (trimesh straight on the bytes, the reader before these checks) reads them.
"""

from __future__ import annotations

import io
import json
import re
import struct
import time
import tracemalloc
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drape.schemas.binary import NpzTooLarge, decode_npz, encode_npz
from drape.service import uploads
from drape.service.errors import DrapeError, InvalidInput, LimitExceeded, MalformedInput

pytestmark = pytest.mark.serial  # its latency bars need the machine to itself

MAXV, MAXF = 3000, 6000  # the service tests' limits
MB = 2**20


def plain_read(data: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """trimesh straight on the bytes, as the service read uploads before these checks: the reference for
    good files, and the contrast for hostile ones. Raises MalformedInput when trimesh fails."""
    try:
        mesh = trimesh.load(io.BytesIO(data), file_type=name.rsplit(".", 1)[-1].lower(), process=False,
                            force="mesh", maintain_order=True)
        return np.asarray(mesh.vertices), np.asarray(mesh.faces)
    except Exception as exc:
        raise MalformedInput(f"trimesh: {exc}", "mesh") from exc


def load(data: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    return uploads.mesh_from_file(data, name, max_vertices=MAXV, max_faces=MAXF)


@contextmanager
def frugal(max_bytes: int = 2 * MB, max_seconds: float = 0.5) -> Iterator[None]:
    """The block must allocate (tracemalloc peak) and take at most this much."""
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        yield
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    elapsed = time.perf_counter() - t0
    assert peak <= max_bytes, f"peak {peak / MB:.1f} MiB"
    assert elapsed <= max_seconds, f"{elapsed:.2f} s"


def refused(error: type[Exception], data: bytes, name: str, *words: str) -> str:
    with frugal(), pytest.raises(error) as info:
        load(data, name)
    detail = str(info.value)
    for w in words:
        assert w in detail, detail
    assert getattr(info.value, "field", "mesh") == "mesh"
    return detail


# ------------------------------------------------------------------------------ glTF builders

def glb(tree: dict, bin_chunk: bytes | None = None) -> bytes:
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text
    if bin_chunk is not None:
        bin_chunk += bytes(-len(bin_chunk) % 4)
        body += struct.pack("<II", len(bin_chunk), 0x004E4942) + bin_chunk
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


TRI_V = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], np.float32)
TRI_F = np.array([0, 1, 2], np.uint32)


def tri_tree(index_count: int = 3, vertex_count: int = 3) -> dict:
    """One triangle: POSITION in bufferView 0 (bytes 0..36), indices in bufferView 1 (36..48)."""
    return {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": vertex_count},
            {"bufferView": 1, "componentType": 5125, "type": "SCALAR", "count": index_count}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                        {"buffer": 0, "byteOffset": 36, "byteLength": 12}],
        "buffers": [{"byteLength": 48}],
    }


TRI_BIN = TRI_V.tobytes() + TRI_F.tobytes()


def grid(n: int = 6) -> trimesh.Trimesh:
    """A small n x n vertex sheet (metres)."""
    ij = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    v = np.c_[ij * 0.05, np.zeros(len(ij))]
    q = np.array([[i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j]
                  for i in range(n - 1) for j in range(n - 1)])
    return trimesh.Trimesh(v, np.r_[q[:, [0, 1, 2]], q[:, [0, 2, 3]]], process=False)


def glb_parts(data: bytes) -> tuple[dict, bytes]:
    n = struct.unpack_from("<I", data, 12)[0]
    tree = json.loads(data[20:20 + n])
    m = struct.unpack_from("<I", data, 20 + n)[0]
    return tree, data[28 + n:28 + n + m]


# ------------------------------------------------------------------- the probe's GLB, and kin

def test_probe_glb_declaring_1_2e9_indices_without_data():
    """The probe's ~400-byte GLB: 1.2e9 indices declared, nothing behind them (trimesh: 24 GB)."""
    tree = tri_tree(index_count=1_200_000_000)
    data = glb(tree)  # no BIN chunk at all
    assert len(data) < 600
    refused(MalformedInput, data, "probe.glb", "BIN chunk")
    refused(MalformedInput, glb(tree, TRI_BIN), "probe.glb", "accessors[1]",
            "beyond bufferViews[1]")
    del tree["accessors"][1]["bufferView"]  # an accessor with no data at all
    refused(MalformedInput, glb(tree, TRI_BIN), "probe.glb", "no bufferView", "1200000000")


def test_glb_declaring_2e8_vertices():
    refused(MalformedInput, glb(tri_tree(vertex_count=200_000_000), TRI_BIN), "v.glb",
            "accessors[0]", "beyond bufferViews[0]")


def test_glb_over_the_limits_with_the_data_present():
    n = MAXV + 1
    v = np.random.default_rng(0).random((n, 3), np.float32) * 0.1
    tree = tri_tree(vertex_count=n)
    tree["bufferViews"] = [{"buffer": 0, "byteLength": 12 * n},
                           {"buffer": 0, "byteOffset": 12 * n, "byteLength": 12}]
    tree["buffers"] = [{"byteLength": 12 * n + 12}]
    refused(LimitExceeded, glb(tree, v.tobytes() + TRI_F.tobytes()), "big.glb", str(MAXV),
            str(n), "vertices")


def test_glb_instances_count_against_the_limits():
    """One mesh placed by many nodes becomes that many copies in trimesh's concatenation."""
    m = grid(30)  # 900 vertices, 1682 triangles
    tree, bin_chunk = glb_parts(m.export(file_type="glb"))
    assert len(load(glb(tree, bin_chunk), "one.glb")[0]) == 900
    tree["nodes"] = [{"children": [1, 2, 3, 4]}]
    tree["nodes"] += [{"mesh": 0, "translation": [0, 0, i]} for i in range(4)]
    tree["scenes"] = [{"nodes": [0]}]
    refused(LimitExceeded, glb(tree, bin_chunk), "four.glb", "at least", str(MAXV))


def test_scene_walk_counts_instances_as_trimesh_makes_them():
    """A node reached by two parents: one instance of a one-primitive mesh, but one per primitive
    per parent of a two-primitive mesh (trimesh's frames)."""
    tree = tri_tree()
    tree["nodes"] = [{"children": [2]}, {"children": [2], "translation": [1, 0, 0]}, {"mesh": 0}]
    tree["scenes"] = [{"nodes": [0, 1]}]
    for primitives, vertices in ((1, 3), (2, 12)):
        tree["meshes"][0]["primitives"] = tree["meshes"][0]["primitives"][:1] * primitives
        data = glb(tree, TRI_BIN)
        v, f = load(data, "dag.glb")
        v0, f0 = plain_read(data, "dag.glb")
        assert len(v) == vertices and np.array_equal(v, v0) and np.array_equal(f, f0)
    with pytest.raises(LimitExceeded, match="at least 12 vertices"):
        uploads.mesh_from_file(data, "dag.glb", max_vertices=11, max_faces=MAXF)


def test_scene_nesting_is_bounded():
    """trimesh's transform lookup costs ~depth^3 per placed instance (numpy's multi_dot chain
    ordering): 200 nested nodes that each place a triangle took it 20 s, 1000 nested nodes above
    one triangle about a minute. Both are refused from the JSON; 32 nested meshes still read."""
    def chain(n: int, every: bool) -> bytes:
        tree = tri_tree()
        mesh = {"mesh": 0} if every else {}
        tree["nodes"] = [{"children": [i + 1], "translation": [0, 0, 0.01], **mesh}
                         for i in range(n - 1)] + [{"mesh": 0}]
        return glb(tree, TRI_BIN)

    refused(LimitExceeded, chain(200, True), "deep.glb", "levels of nested nodes", "64")
    refused(LimitExceeded, chain(1000, False), "deep.glb", "levels of nested nodes", "64")
    refused(LimitExceeded, chain(64, True), "deep.glb", "(node depth)^3",
            str(uploads.MAX_GLTF_PATH_COST))
    t0 = time.perf_counter()
    v, f = load(chain(32, True), "ok.glb")
    assert len(f) == 32 and time.perf_counter() - t0 < 1.0


def test_glb_declarations_beyond_the_bytes():
    tree = tri_tree()
    tree["accessors"][0]["byteOffset"] = 4  # 4 + 36 > the 36-byte view
    refused(MalformedInput, glb(tree, TRI_BIN), "a.glb", "accessors[0]", "beyond bufferViews[0]")
    tree = tri_tree()
    tree["bufferViews"][1]["byteLength"] = 1200
    refused(MalformedInput, glb(tree, TRI_BIN), "a.glb", "bufferViews[1]", "beyond buffers[0]")
    tree = tri_tree()
    tree["buffers"][0]["byteLength"] = 4800
    refused(MalformedInput, glb(tree, TRI_BIN), "a.glb", "buffers[0]", "4800", "48")
    tree = tri_tree()
    tree["bufferViews"][0]["byteStride"] = 4  # below a VEC3's 12 bytes
    refused(MalformedInput, glb(tree, TRI_BIN), "a.glb", "byteStride")
    data = glb(tri_tree(), TRI_BIN)
    refused(MalformedInput, data[:-8], "a.glb", "declares")  # header length beyond the data
    lying_chunk = bytearray(data)
    struct.pack_into("<I", lying_chunk, 12, 10**9)  # the JSON chunk claims 1e9 bytes
    refused(MalformedInput, bytes(lying_chunk), "a.glb", "chunk")


def test_glb_features_refused_clearly():
    tree = tri_tree()
    tree["accessors"][1]["sparse"] = {"count": 1, "indices": {}, "values": {}}
    refused(InvalidInput, glb(tree, TRI_BIN), "a.glb", "sparse")
    tree = tri_tree()
    tree["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    refused(InvalidInput, glb(tree, TRI_BIN), "a.glb", "Draco")
    tree = tri_tree()
    tree["extensionsRequired"] = ["EXT_meshopt_compression"]
    refused(InvalidInput, glb(tree, TRI_BIN), "a.glb", "meshopt")
    tree = tri_tree()
    tree["meshes"][0]["primitives"][0]["mode"] = 1
    refused(InvalidInput, glb(tree, TRI_BIN), "a.glb", "mode 1", "triangle")


def test_gltf_external_uri_refused_and_data_uri_read():
    tree = tri_tree()
    tree["buffers"][0]["uri"] = "../../etc/passwd"
    refused(InvalidInput, json.dumps(tree).encode(), "a.gltf", "external file", "data: URIs")
    tree["buffers"][0]["uri"] = "data:application/octet-stream;base64,"
    refused(MalformedInput, json.dumps(tree).encode(), "a.gltf", "only 0 are present")
    import base64

    encoded = base64.b64encode(TRI_BIN).decode()
    broken = dict(tree, buffers=[dict(tree["buffers"][0], uri=tree["buffers"][0]["uri"] + "*" + encoded[1:])])
    # not base64: said so (b64decode dropped the stray characters and the bytes left were "only N present")
    refused(MalformedInput, json.dumps(broken).encode(), "a.gltf", "base64 data is unreadable")
    wrapped = "\n".join(encoded[i:i + 16] for i in range(0, len(encoded), 16))  # line breaks are not data
    tree["buffers"][0]["uri"] += wrapped
    v, f = load(json.dumps(tree).encode(), "a.gltf")
    assert np.array_equal(v, TRI_V) and f.tolist() == [[0, 1, 2]]


def test_gltf_json_bounded_in_size_and_nesting():
    deep = b'{"asset": {"version": "2.0"}, "extras": ' + b"[" * 50_000 + b"]" * 50_000 + b"}"
    refused(MalformedInput, deep, "deep.gltf", "unreadable", "RecursionError")
    refused(MalformedInput, _glb_raw_json(deep), "deep.glb", "RecursionError")
    wide = b'{"extras": [' + b"0," * 300_000 + b"0]}"
    refused(LimitExceeded, wide, "wide.gltf", str(uploads.MAX_JSON_TOKENS))


def _glb_raw_json(text: bytes) -> bytes:
    text += b" " * (-len(text) % 4)
    return struct.pack("<4sII", b"glTF", 2, 20 + len(text)) + struct.pack("<II", len(text),
                                                                          0x4E4F534A) + text


def test_node_cycles_end():
    tree = tri_tree()
    tree["nodes"] = [{"mesh": 0, "children": [1]}, {"children": [0, 1]}]
    try:
        v, f = load(glb(tree, TRI_BIN), "cycle.glb")
    except DrapeError:
        pass
    else:
        assert f.tolist() == [[0, 1, 2]]


def png_header(width: int, height: int) -> bytes:
    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + body))
        return struct.pack(">I", len(body)) + kind + body + crc

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64))
            + chunk(b"IEND", b""))


def test_textures_are_never_decoded(monkeypatch):
    """A 16000 x 11000 PNG texture (2.2 GB decoded in the probe): PIL is never even asked."""
    import PIL.Image

    png = png_header(16000, 11000)
    tree = tri_tree()
    uv = np.zeros((3, 2), np.float32).tobytes()
    tree["bufferViews"] += [{"buffer": 0, "byteOffset": 48, "byteLength": 24},
                            {"buffer": 0, "byteOffset": 72, "byteLength": len(png)}]
    tree["buffers"] = [{"byteLength": 72 + len(png)}]
    tree["accessors"].append({"bufferView": 2, "componentType": 5126, "type": "VEC2", "count": 3})
    tree["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 2
    tree["meshes"][0]["primitives"][0]["material"] = 0
    tree["images"] = [{"bufferView": 3, "mimeType": "image/png"}]
    tree["samplers"] = [{}]
    tree["textures"] = [{"source": 0, "sampler": 0}]
    tree["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    data = glb(tree, TRI_BIN + uv + png)
    opened: list[object] = []

    def no_images(*args, **kwargs):
        opened.append(args)
        raise RuntimeError("an image was opened")

    monkeypatch.setattr(PIL.Image, "open", no_images)
    v, f = load(data, "textured.glb")
    assert np.array_equal(v, TRI_V) and f.tolist() == [[0, 1, 2]]
    assert opened == []
    try:  # today's reader hands the PNG to PIL (which then decodes it on use)
        plain_read(data, "textured.glb")
    except DrapeError:
        pass
    assert len(opened) == 1


def test_interleaved_positions_read_as_trimesh_reads_them():
    """A strided bufferView (position + normal per vertex) is copied densely, same geometry."""
    m = grid(5)
    inter = np.zeros((len(m.vertices), 6), np.float32)
    inter[:, :3] = m.vertices
    inter[:, 3:] = m.vertex_normals
    faces = m.faces.astype(np.uint16).ravel()
    blob = inter.tobytes() + faces.tobytes()
    n = len(inter)
    tree = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "translation": [0.0, 0.5, 0.0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": n},
            {"bufferView": 0, "byteOffset": 12, "componentType": 5126, "type": "VEC3", "count": n},
            {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": len(faces)}],
        "bufferViews": [{"buffer": 0, "byteLength": 24 * n, "byteStride": 24},
                        {"buffer": 0, "byteOffset": 24 * n, "byteLength": 2 * len(faces)}],
        "buffers": [{"byteLength": len(blob)}],
    }
    data = glb(tree, blob)
    v, f = load(data, "inter.glb")
    v0, f0 = plain_read(data, "inter.glb")
    assert np.array_equal(v, v0) and np.array_equal(f, f0)
    assert np.allclose(v, m.vertices + [0, 0.5, 0]) and np.array_equal(f, m.faces)


# ----------------------------------------------------------------------------------------- OBJ

def test_obj_too_many_vertex_lines():
    data = b"v 0 0 0\n" * (MAXV + 1) + b"f 1 2 3\n"
    refused(LimitExceeded, data, "a.obj", str(MAXV + 1), str(MAXV), "vertices")


def test_obj_quads_make_more_triangles_than_the_limit():
    data = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n" + b"f 1 2 3 4\n" * (MAXF // 2 + 1)
    refused(LimitExceeded, data, "quads.obj", str(MAXF), "triangles")
    one_face = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf" + b" 1 2 3" * (MAXF // 3 + 1) + b"\n"
    refused(LimitExceeded, one_face, "ngon.obj", str(MAXF), "triangles")
    continued = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n" + b"f 1 2 \\\n3 4\n" * (MAXF // 2 + 1)
    refused(LimitExceeded, continued, "continued.obj", str(MAXF))  # trimesh joins `\` lines
    quads = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n" + b"f 1 2 3 4\n" * 10
    assert load(quads, "ok.obj")[1].shape == (20, 3)


def test_obj_face_index_values_are_bounded():
    """trimesh's maintain_order path allocates 3 x (largest index) int64s: refused from the text."""
    data = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 200000/1\n"
    refused(MalformedInput, data, "idx.obj", "more than 1 digit", "beyond the file's 3 vertices")
    many = b"v 0 0 0\n" * 1000 + b"vn 0 0 1\nf 1//1 2//1 3//1\nf 1//1 2//1 1001//1\n"
    refused(MalformedInput, many, "idx.obj", "index 1001", "beyond the file's 1000 vertices")
    assert load(many.replace(b"1001", b"1000"), "ok.obj")[1].shape == (2, 3)
    # a relative (negative) index is named with its sign (f -1 -2 -9 said "index 9")
    relative = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -9\n"
    refused(MalformedInput, relative, "rel.obj", "index -9", "beyond the file's 3 vertices")
    tracemalloc.start()
    try:  # today's reader on the 47-byte file: tens of MB (an index of 2e9: hundreds of GB)
        plain_read(data, "idx.obj")
    except DrapeError:
        pass
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak > 10 * MB


def test_obj_material_blocks_neither_copy_nor_multiply_the_vertices():
    """trimesh (maintain_order) gives every `usemtl` block a copy of all the vertices: 1,000 blocks over 2,000
    `v` lines built 2 million vertices before the count could refuse them, and a garment of two materials came
    back twice over. Materials are not read: the vertices are the file's own, once."""
    two = b"mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\nf 1 2 3\n  usemtl b\nf 2 4 3\n"
    v, f = load(two, "two.obj")
    np.testing.assert_array_equal(v, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    np.testing.assert_array_equal(f, [[0, 1, 2], [1, 3, 2]])
    assert len(plain_read(two, "two.obj")[0]) == 8  # the reader as it is: each block its own copy
    many = b"".join(b"v %d 0 %d\n" % (i, i % 7) for i in range(2000)) + b"usemtl m\nf 1 2 3\n" * 1000
    with frugal(max_bytes=4 * MB, max_seconds=1.0):
        v, f = load(many, "many.obj")
    assert v.shape == (2000, 3) and f.shape == (1000, 3)


def test_obj_texture_coordinate_lines_are_bounded():
    n = MAXV + 3 * MAXF + 1
    refused(LimitExceeded, b"v 0 0 0\n" * 3 + b"vt 0 0\n" * n + b"f 1 2 3\n", "vt.obj", str(n))


def test_obj_check_stays_fast_on_a_big_file():
    """8 MiB of comments around a mesh at the limits: the count is bytes-level."""
    m = grid(50)  # 2500 vertices, 4802 triangles
    data = b"# padding padding padding\n" * (8 * MB // 27) + m.export(file_type="obj").encode()
    t0 = time.perf_counter()
    uploads._check_obj(data, MAXV, MAXF)
    assert time.perf_counter() - t0 < 0.5


# ----------------------------------------------------------------------------------------- PLY

def ply_header(fmt: str, vertices: int, faces: int) -> bytes:
    return (f"ply\nformat {fmt} 1.0\nelement vertex {vertices}\nproperty float x\n"
            f"property float y\nproperty float z\nelement face {faces}\n"
            "property list uchar int vertex_indices\nend_header\n").encode()


def test_binary_ply_declaring_1e9_vertices_without_data():
    refused(LimitExceeded, ply_header("binary_little_endian", 10**9, 1), "a.ply", str(MAXV))
    refused(MalformedInput, ply_header("binary_little_endian", MAXV, 1), "a.ply",
            "bytes of data")
    body = np.zeros((3, 3), "<f4").tobytes() + b"\xff" + bytes(4 * 255)  # a 255-gon first face
    refused(LimitExceeded, ply_header("binary_little_endian", 3, MAXF // 253 + 1) + body, "a.ply",
            "triangles")


def test_ascii_ply_lines_and_triangles_are_bounded():
    head = ply_header("ascii", 3, 1)
    rows = b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    assert load(head + rows, "a.ply")[1].tolist() == [[0, 1, 2]]
    refused(MalformedInput, head + rows + b"\n" * 100_000, "a.ply", "lines")
    ngon = b"0 0 0\n1 0 0\n0 1 0\n" + f"{MAXF + 3}".encode() + b" 0 1 2" * (MAXF // 3 + 1) + b"\n"
    refused(LimitExceeded, head + ngon, "a.ply", "triangles", str(MAXF))
    refused(MalformedInput, head.replace(b"vertex 3", b"vertex -3"), "a.ply", "negative")


# ---------------------------------------------------------------------------- good files read

@pytest.fixture(scope="module")
def garment() -> trimesh.Trimesh:
    from drape.assets.outfits import generate_outfit

    return generate_outfit("tshirt", vertices=800).to_trimesh()


def good_files(m: trimesh.Trimesh) -> dict[str, bytes]:
    scene = trimesh.Scene()
    scene.add_geometry(m, node_name="a")
    shift = trimesh.transformations.translation_matrix([0, 0, 1])
    scene.add_geometry(m, node_name="b", transform=shift)
    return {
        "a.obj": m.export(file_type="obj").encode(),
        "ascii.ply": m.export(file_type="ply", encoding="ascii"),
        "binary.ply": m.export(file_type="ply"),
        "a.glb": m.export(file_type="glb"),
        "scene.glb": scene.export(file_type="glb"),
        "scene.gltf": trimesh.exchange.gltf.export_gltf(scene, embed_buffers=True)["model.gltf"],
    }


def test_good_files_read_as_before(garment):
    for name, data in good_files(garment).items():
        v, f = load(data, name)
        v0, f0 = plain_read(data, name)
        assert np.array_equal(v, v0) and np.array_equal(f, f0), name
        assert f.shape[1] == 3 and len(f) >= len(garment.faces), name
        if "scene" not in name:
            assert np.allclose(v, garment.vertices, atol=1e-6), name
            assert np.array_equal(f, garment.faces), name


def test_unsupported_suffix_is_422():
    with pytest.raises(InvalidInput, match="file name must end"):
        load(b"solid x", "a.stl")


# ------------------------------------------------------------------------------------------ npz

def npy_bytes(shape: tuple[int, ...], descr: str = "<f4", data: bytes = b"") -> bytes:
    buf = io.BytesIO()
    header = {"descr": descr, "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(buf, header)
    return buf.getvalue() + data


GOOD = {"vertices": np.arange(12, dtype=np.float32).reshape(4, 3), "faces": np.array([[0, 1, 2]]),
        "name": np.array("three"), "f": np.asfortranarray(np.ones((3, 2), ">f8"))}


@pytest.fixture(scope="session")
def npz_bomb() -> bytes:
    """A small npz beside a deflated 200 MB member of zeros (about 200 KB on the wire)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for k, a in GOOD.items():
            with zf.open(k + ".npy", "w") as f:
                np.lib.format.write_array(f, a)
        with zf.open("bomb.npy", "w") as f:
            f.write(npy_bytes((50 * MB,)))
            zeros = bytes(8 * MB)
            for _ in range(25):
                f.write(zeros)
    return buf.getvalue()


def test_decode_npz_unchanged_without_arguments():
    out = decode_npz(encode_npz(GOOD))
    assert out.keys() == GOOD.keys()
    for k, a in GOOD.items():
        assert out[k].dtype == a.dtype and np.array_equal(out[k], a) and out[k].flags.writeable


def test_npz_names_never_inflate_other_members(npz_bomb):
    assert len(npz_bomb) < 2 * MB
    with frugal(max_bytes=MB, max_seconds=0.2):
        out = decode_npz(npz_bomb, ["vertices", "faces", "absent"])
    assert out.keys() == {"vertices", "faces"} and np.array_equal(out["vertices"], GOOD["vertices"])
    with frugal(max_bytes=MB, max_seconds=0.2), pytest.raises(NpzTooLarge, match="'bomb'"):
        decode_npz(npz_bomb, ["vertices", "bomb"], max_bytes=16 * MB)


def zip_of(members: dict[str, bytes], method: int = zipfile.ZIP_STORED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", method) as zf:
        for k, v in members.items():
            zf.writestr(k, v)
    return buf.getvalue()


def test_npz_header_declaring_1e10_floats_is_refused_before_reading():
    data = zip_of({"vertices.npy": npy_bytes((10**10,), data=bytes(16))})
    with frugal(), pytest.raises(NpzTooLarge, match="vertices"):
        decode_npz(data, max_bytes=64 * MB)
    with frugal(), pytest.raises(ValueError, match="vertices.*40000000000 bytes"):
        decode_npz(data)  # no limit: the header disagrees with the archive's declared size


def test_npz_narrow_numbers_count_as_four_bytes_against_the_limit():
    """The readers widen numbers to float64 / int64: an int8 member within max_bytes by its own bytes grew 8-fold
    past it (an 88 kB upload of int8 vertices took 770 MiB before the vertex limit's 413). Every element counts as
    at least 4 bytes, refused before it is inflated; float32 at the limit reads as before."""
    buf = io.BytesIO()
    np.savez_compressed(buf, vertices=np.zeros((MB, 3), np.int8))  # 3 MiB of int8, 12 MiB counted
    with frugal(max_bytes=MB), pytest.raises(NpzTooLarge, match=r"'vertices'.*3145728 bytes, counted as 12582912"):
        decode_npz(buf.getvalue(), max_bytes=4 * MB)
    zero_size = zip_of({"body.npy": npy_bytes((10**9,), "<U0")})  # no bytes at all, 4 GB once allocated
    with frugal(max_bytes=MB), pytest.raises(NpzTooLarge, match="'body'"):
        decode_npz(zero_size, max_bytes=4 * MB)
    floats = encode_npz({"vertices": np.zeros((MB // 3, 3), np.float32)})
    assert decode_npz(floats, max_bytes=4 * MB)["vertices"].shape == (MB // 3, 3)


def test_npz_lying_uncompressed_size():
    """The zip entry says 4128 bytes (header + 1000 floats); its data inflates to 8 MiB."""
    raw = npy_bytes((1000,)) + bytes(8 * MB)
    data = bytearray(zip_of({"vertices.npy": raw}, zipfile.ZIP_DEFLATED))
    declared = len(npy_bytes((1000,))) + 4000
    local, central = data.find(b"PK\x03\x04"), data.find(b"PK\x01\x02")
    struct.pack_into("<I", data, local + 22, declared)
    struct.pack_into("<I", data, central + 24, declared)
    with frugal(), pytest.raises(ValueError, match="CRC"):
        decode_npz(bytes(data))
    struct.pack_into("<I", data, central + 24, 10**9)  # more than 1032:1 of its compressed bytes
    with frugal(), pytest.raises(ValueError, match="cannot hold"):
        decode_npz(bytes(data))


unpickled: list[int] = []


def _unpickle_marker() -> None:
    unpickled.append(1)


class Boom:
    def __reduce__(self):
        return (_unpickle_marker, ())


def test_npz_object_and_void_arrays_refused():
    buf = io.BytesIO()
    np.savez(buf, vertices=np.array([Boom()], dtype=object))
    with pytest.raises(ValueError, match="pickled or object arrays are refused"):
        decode_npz(buf.getvalue())
    assert unpickled == []
    void = zip_of({"v.npy": npy_bytes((2,), "|V4", bytes(8))})
    with pytest.raises(ValueError, match="refused"):
        decode_npz(void)
    with pytest.raises(ValueError, match="not a readable .npy"):
        decode_npz(zip_of({"notes.txt": b"hello"}))


def test_npz_directory_is_bounded():
    many = zip_of({f"a{i}.npy": b"" for i in range(1100)})
    with frugal(max_seconds=0.2), pytest.raises(ValueError, match="members"):
        decode_npz(many, ["a0"])


# ---------------------------------------------------------------------- mutations (hypothesis)

def _mesh_samples() -> dict[str, bytes]:
    m = grid(4)
    return {"g.obj": m.export(file_type="obj").encode(),
            "g.ply": m.export(file_type="ply", encoding="ascii"),
            "b.ply": m.export(file_type="ply"),
            "g.glb": m.export(file_type="glb")}


SAMPLES = _mesh_samples()
BIG_INTS = st.one_of(st.integers(0, 100), st.integers(0, 2**40),
                    st.sampled_from([2**31, 2**32 - 1]))


def npz_with_header(draw: st.DrawFn) -> bytes:
    """GOOD with one member's declared shape changed; its data is kept, or matched when small."""
    members = {}
    for k, a in GOOD.items():
        buf = io.BytesIO()
        np.lib.format.write_array(buf, a)
        members[k + ".npy"] = buf.getvalue()
    key = draw(st.sampled_from(sorted(members)))
    a = GOOD[key.removesuffix(".npy")]
    shape = list(a.shape) or [1]
    shape[draw(st.integers(0, len(shape) - 1))] = draw(BIG_INTS)
    nbytes = int(np.prod(shape)) * a.dtype.itemsize
    body = bytes(nbytes) if nbytes <= 4096 and draw(st.booleans()) else members[key][-a.nbytes:]
    members[key] = npy_bytes(tuple(shape), a.dtype.str, body)
    return zip_of(members, draw(st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED])))


@st.composite
def mutated(draw: st.DrawFn, original: bytes, glb_file: bool = False, npz: bool = False) -> bytes:
    data = bytearray(original)
    op = draw(st.sampled_from(["truncate", "flip", "count"]))
    if op == "truncate":
        return bytes(data[:draw(st.integers(0, len(data)))])
    if op == "flip":
        for _ in range(draw(st.integers(1, 8))):
            data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
        return bytes(data)
    if npz:
        return npz_with_header(draw)
    if glb_file:  # change a declared count, offset or length and rebuild the GLB consistently
        tree, bin_chunk = glb_parts(original)
        section = draw(st.sampled_from(["accessors", "bufferViews", "buffers"]))
        item = draw(st.sampled_from(tree[section]))
        key = draw(st.sampled_from(["count", "byteOffset", "byteLength", "byteStride"]))
        item[key] = draw(BIG_INTS)
        return glb(tree, bin_chunk)
    runs = [m.span() for m in re.finditer(rb"\d+", bytes(data[:2000]))]
    start, end = draw(st.sampled_from(runs))
    return bytes(data[:start]) + str(draw(BIG_INTS)).encode() + bytes(data[end:])


@settings(max_examples=80, deadline=2000, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_mutated_meshes_end_in_a_mesh_or_a_domain_error(data):
    name = data.draw(st.sampled_from(sorted(SAMPLES)))
    blob = data.draw(mutated(SAMPLES[name], name.endswith(".glb")))
    tracemalloc.start()
    try:
        v, f = load(blob, name)
        assert v.ndim == 2 and v.shape[1] == 3 and f.ndim == 2 and f.shape[1] == 3
        assert len(v) <= MAXV + 3 * MAXF and len(f) <= MAXF
    except DrapeError:
        pass
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peak < 64 * MB


NPZ_SAMPLE = encode_npz(GOOD)


@settings(max_examples=80, deadline=2000)
@given(st.data())
def test_mutated_npz_end_in_arrays_or_value_error(data):
    blob = data.draw(mutated(NPZ_SAMPLE, npz=True))
    names = data.draw(st.sampled_from([None, ["vertices", "faces"]]))
    tracemalloc.start()
    try:
        out = decode_npz(blob, names, max_bytes=4 * MB)
        assert all(isinstance(a, np.ndarray) for a in out.values())
    except ValueError:
        pass
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peak < 16 * MB
