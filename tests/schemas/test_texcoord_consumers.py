"""The real consumers of drape's TEXCOORD_0 read the UVs as drape means them (docs/export.md, "Texture
coordinates"): a skinned, morphed, animated GLB written by `skinned_glb` from a small garment whose UVs
(per face corner, OBJ's convention: v from the image's bottom) have seams, islands and tiling values
outside [0, 1], is loaded by

- three.js (GLTFLoader, headless Chromium; tests/schemas/threejs_player.py): its `geometry.attributes.uv`,
  read per face corner through the geometry's index, is the UVs in glTF's convention (u, 1 - v): three.js
  keeps glTF's convention and samples glTF textures with flipY = false;
- Blender (its glTF importer, bpy in .venv-blender, a subprocess as bench/blender_eval.py runs it): the
  mesh's active UV layer, per loop, is the UVs in OBJ's convention (the importer flips v back to the
  bottom). Blender's faces are matched to drape's by their corners' positions (Y-up to Z-up undone), not
  by order. Skipped where .venv-blender is missing.

Each check fails on an unflipped (or doubly flipped) v, and on a UV landing on the other side of a seam.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
from threejs_player import THREE_VERSION, page_js, run_node

from drape.assets.body import load_body
from drape.schemas.gltf import Animation, Skeleton, SkinnedMesh, skinned_glb, split_uv_seams

ROOT = Path(__file__).resolve().parents[2]
BLENDER_PY = ROOT / ".venv-blender" / "bin" / "python"
UV_ATOL = 1e-6  # float32 UVs read back as float32: only 1 - (1 - v) rounding
POS_ATOL = 1e-5  # m: corner positions, float32


@pytest.fixture(scope="module")
def garment():
    """-> (glb bytes, vertices (N, 3), faces (F, 3), uv_corners (F, 3, 2) OBJ convention, written vertex count):
    a 13 x 13 grid (169 vertices, 288 triangles) on the chest, its UVs in three islands (a seam down the
    middle column, the top row's faces each their own island) and a tiled patch with u, v outside [0, 1]."""
    body = load_body("neutral")
    n = 13
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")  # i: column (x), j: row (y)
    x, y = -0.3 + 0.6 * i / (n - 1), 1.0 + 0.5 * j / (n - 1)
    z = 0.12 + 0.03 * np.sin(3 * x) * np.cos(4 * y)  # not flat: no two corners share a position
    verts = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    vid = (i * n + j)
    quads = np.stack([vid[:-1, :-1], vid[1:, :-1], vid[1:, 1:], vid[:-1, 1:]], -1).reshape(-1, 4)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])  # counter-clockwise seen from +z
    # per vertex: a grid in UV space, v rising with y (OBJ: from the image's bottom), asymmetric in v
    base = np.stack([i / (n - 1), j / (n - 1)], -1).reshape(-1, 2)
    uv_corners = (0.05 + 0.4 * base[faces]).astype(np.float32)
    col = i[:-1, :-1].reshape(-1)  # faces' quad column and row, as `quads`
    row = j[:-1, :-1].reshape(-1)
    col, row = np.concatenate([col, col]), np.concatenate([row, row])
    right = col >= (n - 1) // 2  # faces right of the middle column: another island, a seam between
    uv_corners[right] += np.float32([0.5, 0.5])
    top = row == n - 2  # the top row's faces: each its own small island
    k = np.flatnonzero(top)
    uv_corners[k] = (np.float32([0.02, 0.9]) + 0.03 * np.arange(len(k))[:, None, None] * np.float32([1, 0])
                     + np.float32([[0, 0], [0.02, 0], [0.01, 0.05]]))
    tiled = (row == 0) & (col < 3)  # tiling: u and v outside [0, 1]
    uv_corners[tiled] = uv_corners[tiled] * np.float32([3.0, 2.5]) - np.float32([1.2, 0.75])
    uv_corners[tiled, :, 1] -= np.float32(0.5)
    assert (uv_corners[..., 1] < 0).any() and (uv_corners[..., 0] < 0).any()
    # skinned: each vertex the weights of the nearest body vertex; two morph targets and a 3-frame motion
    near = ((verts[:, None] - body.vertices[None]) ** 2).sum(-1).argmin(1)
    weights = body.weights[near]
    rng = np.random.default_rng(4)
    targets = rng.normal(scale=0.005, size=(2, len(verts), 3)).astype(np.float32)
    poses = rng.normal(scale=0.1, size=(3, 24, 3))
    trans = np.zeros((3, 3))
    keys = np.float32([[0, 0], [0.5, 1], [1, 0.2]])
    glb = skinned_glb(Skeleton(body.joint_names, body.parents, body.joints),
                      [SkinnedMesh("outfit", verts, faces, weights, targets, ("a", "b"), uv_corners)],
                      Animation(poses, trans, 30.0, keys))
    source, _, _ = split_uv_seams(faces, uv_corners, len(verts))
    assert len(source) > len(verts) + 20  # seams, islands: many vertices written more than once
    return glb, verts, faces, uv_corners, len(source)


def test_the_garment_has_seams_and_asymmetric_v(garment):
    """What the checks below can tell: flipping v (or not) changes every corner, and a vertex's copies differ."""
    _, verts, faces, uv, written = garment
    assert np.abs(uv[..., 1] - (1 - uv[..., 1])).min() > 0.01
    assert written >= len(verts) + 30


READ_MODULE = r"""import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
window.drapeRead = async () => {
  const data = await (await fetch('/model.glb')).arrayBuffer();
  const gltf = await new GLTFLoader().parseAsync(data, '');
  let mesh = null;
  gltf.scene.traverse((o) => { if (o.isMesh && o.name === 'outfit') mesh = o; });
  if (!mesh) throw new Error('no mesh named outfit');
  const g = mesh.geometry, uv = g.attributes.uv;
  return {revision: THREE.REVISION, skinned: mesh.isSkinnedMesh === true, attributes: Object.keys(g.attributes),
          uv: uv ? {array: Array.from(uv.array), itemSize: uv.itemSize, normalized: uv.normalized,
                    interleaved: uv.isInterleavedBufferAttribute === true, type: uv.array.constructor.name} : null,
          position: Array.from(g.attributes.position.array), index: g.index ? Array.from(g.index.array) : null};
};
"""
THREE_JS = page_js(READ_MODULE, "() => window.drapeRead()")


def test_threejs_reads_texcoord_0_as_gltf_uv_per_face_corner(garment):
    glb, verts, faces, uv_corners, written = garment
    with tempfile.TemporaryDirectory() as tmp:
        path, spec = Path(tmp) / "model.glb", Path(tmp) / "spec.json"
        path.write_bytes(glb)
        spec.write_text("{}")
        out = run_node(THREE_JS, str(path), str(spec), timeout=180)
    assert not out["problems"], out["problems"][:10]
    assert out["revision"] == THREE_VERSION.split(".")[1] and out["skinned"]
    assert out["attributes"][:1] == ["position"] and "uv" in out["attributes"], out["attributes"]
    assert "uv1" not in out["attributes"]  # TEXCOORD_0 alone (TEXCOORD_1 would be uv1 since r151)
    uv = out["uv"]
    assert uv["itemSize"] == 2 and not uv["normalized"] and uv["type"] == "Float32Array", uv
    three_uv = np.asarray(uv["array"], np.float64).reshape(-1, 2)
    position = np.asarray(out["position"], np.float64).reshape(-1, 3)
    index = np.asarray(out["index"], np.int64).reshape(-1, 3)
    assert len(three_uv) == len(position) == written and index.shape == faces.shape
    # the index buffer's triangles are drape's faces, in order, on copies of their own vertices
    np.testing.assert_allclose(position[index], verts[faces], atol=POS_ATOL)
    want = np.stack([uv_corners[..., 0], 1.0 - uv_corners[..., 1]], -1)  # glTF: v from the image's top
    got = three_uv[index]
    err = np.abs(got - want).max()
    print(f"three.js r{out['revision']}: uv per face corner vs (u, 1 - v): max abs diff {err:.3g} "
          f"({len(three_uv)} vertices for {len(verts)}, attributes {out['attributes']})")
    assert err <= UV_ATOL, err


BLENDER_SCRIPT = r"""
import json, sys
import bpy
import numpy as np

glb, out = sys.argv[1], sys.argv[2]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=glb)
# an animated-weights node: the importer may leave an Empty named 'outfit' and put the mesh in a child object
(obj,) = [o for o in bpy.data.objects if o.type == 'MESH' and o.data.name == 'outfit']
me = obj.data
co = np.empty(len(me.vertices) * 3, np.float32)
me.vertices.foreach_get('co', co)
loop_vertex = np.empty(len(me.loops), np.int64)
me.loops.foreach_get('vertex_index', loop_vertex)
loop_start = np.empty(len(me.polygons), np.int64)
me.polygons.foreach_get('loop_start', loop_start)
loop_total = np.empty(len(me.polygons), np.int64)
me.polygons.foreach_get('loop_total', loop_total)
layer = me.uv_layers.active
uv = np.empty(len(me.loops) * 2, np.float32)
layer.data.foreach_get('uv', uv)
np.savez(out, co=co.reshape(-1, 3), matrix_world=np.array(obj.matrix_world, np.float64), loop_vertex=loop_vertex,
         loop_start=loop_start, loop_total=loop_total, uv=uv.reshape(-1, 2),
         info=json.dumps({'bpy': bpy.app.version_string, 'object': obj.name, 'layers': [l.name for l in me.uv_layers],
                          'active': layer.name}))
"""


def test_blender_reads_texcoord_0_as_obj_uv_per_loop(garment):
    if not BLENDER_PY.exists():
        pytest.skip(f"{BLENDER_PY} is missing (bpy's own venv: `make check-blender` creates it)")
    glb, verts, faces, uv_corners, written = garment
    with tempfile.TemporaryDirectory() as tmp:
        path, out = Path(tmp) / "model.glb", Path(tmp) / "blender.npz"
        path.write_bytes(glb)
        done = subprocess.run([str(BLENDER_PY), "-c", BLENDER_SCRIPT, str(path), str(out)], capture_output=True,
                              text=True, timeout=120, cwd=tmp)
        assert done.returncode == 0 and out.exists(), (done.stderr[-3000:], done.stdout[-1000:])
        b = dict(np.load(out))
    info = json.loads(str(b["info"]))
    m = b["matrix_world"]
    world = b["co"].astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    gltf = np.stack([world[:, 0], world[:, 2], -world[:, 1]], 1)  # the importer maps (x, y, z) to (x, -z, y)
    # every Blender vertex at a drape vertex
    d = ((gltf[:, None] - verts[None].astype(np.float64)) ** 2).sum(-1)
    near = d.argmin(1)
    assert np.sqrt(d[np.arange(len(near)), near]).max() <= POS_ATOL
    # every Blender polygon a triangle of drape's, each drape face met once
    assert (b["loop_total"] == 3).all(), np.unique(b["loop_total"])
    loops = b["loop_start"][:, None] + np.arange(3)
    corner_vertex = near[b["loop_vertex"][loops]]  # (P, 3) drape vertex of each loop
    face_of = {tuple(sorted(f)): k for k, f in enumerate(faces.tolist())}
    which = np.array([face_of.get(tuple(sorted(c)), -1) for c in corner_vertex.tolist()])
    assert (which >= 0).all() and np.array_equal(np.sort(which), np.arange(len(faces)))
    # each loop's corner: the position of its vertex within drape's face
    corner = np.argmax(faces[which][:, None, :] == corner_vertex[:, :, None], axis=2)  # (P, 3)
    want = uv_corners[which[:, None], corner]  # OBJ convention: the importer flips v back
    got = b["uv"][loops]
    err = np.abs(got.astype(np.float64) - want).max()
    print(f"Blender {info['bpy']} ({info['object']}, UV layers {info['layers']}, active {info['active']}): "
          f"uv per loop vs OBJ (u, v): max abs diff {err:.3g}; {len(b['co'])} vertices "
          f"(drape {len(verts)}, written {written}), {len(b['loop_start'])} polygons")
    assert err <= UV_ATOL, err
