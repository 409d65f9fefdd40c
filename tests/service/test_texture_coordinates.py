"""A garment's texture coordinates survive the rig: an uploaded OBJ's `vt` (or a GLB's TEXCOORD_0) come back in the
rig's GLB and in every GLB animate makes of its outfit_id, a seam's vertex written once per side (a game team's
textured garment came back untextured: the GLBs carried positions, skin and morphs only)."""

import io
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "schemas"))
from glb_player import GlbPlayer  # noqa: E402
from gltf_validator import validate  # noqa: E402

from drape.assets.outfits import generate_outfit  # noqa: E402
from drape.schemas.binary import NPZ, decode_npz  # noqa: E402
from drape.schemas.gltf import GLB  # noqa: E402

EXTERNAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "external"


@pytest.fixture(scope="module")
def textured():
    """A generated t-shirt as an OBJ with one UV island per half (x < 0 and x >= 0: the middle is a seam), in
    a material (the service reads the file without it): (obj bytes, vertices, faces, uv corners (F, 3, 2))."""
    o = generate_outfit("tshirt", vertices=500, seed=4)
    v, f = o.vertices.astype(np.float64), o.faces
    per_vertex = (v[:, :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], axis=0)
    right = v[f].mean(1)[:, 0] >= 0  # each face's island
    corners = per_vertex[f] * 0.5 + np.where(right, 0.5, 0.0)[:, None, None] * [1, 0]
    table, refs = np.unique(corners.reshape(-1, 2), axis=0, return_inverse=True)
    refs = refs.reshape(-1, 3)
    text = ["mtllib shirt.mtl", "usemtl cotton"] + [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in v]
    text += [f"vt {a:.9g} {b:.9g}" for a, b in table]
    text += ["f " + " ".join(f"{vi + 1}/{ti + 1}" for vi, ti in zip(face, ref, strict=True))
             for face, ref in zip(f, refs, strict=True)]
    return ("\n".join(text) + "\n").encode(), v, f, table[refs].astype(np.float32)


def _corner_uv(glb: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The outfit mesh's (positions (C, 3), uv per face corner (F, 3, 2) in OBJ's convention) as written."""
    player = GlbPlayer(glb)
    prim = player.doc.meshes[0].primitives[0]
    tex = player.accessor(prim.attributes.TEXCOORD_0)
    faces = player.accessor(prim.indices).reshape(-1, 3)
    uv = np.column_stack([tex[:, 0], 1.0 - tex[:, 1]])[faces]
    return player.accessor(prim.attributes.POSITION)[faces], uv


def _same_corners(glb: bytes, vertices: np.ndarray, faces: np.ndarray, uv_corners: np.ndarray) -> None:
    """Each written face's corners hold the file's positions and UVs (faces in the file's order)."""
    positions, uv = _corner_uv(glb)
    np.testing.assert_allclose(positions, vertices[faces], atol=1e-6)
    np.testing.assert_allclose(uv, uv_corners, atol=1e-6)


def test_an_objs_uvs_come_back_in_the_rig_glb_and_in_animates(http, textured):
    data, v, f, uv = textured
    r = http.post("/v1/outfits/rig", files={"mesh": ("shirt.obj", data)}, headers={"Accept": GLB})
    assert r.status_code == 200, r.text[:300]
    report = validate(r.content)
    assert report["errors"] == 0, report["messages"]
    _same_corners(r.content, v, f, uv)
    import trimesh  # the rest normals go out too, on the outer side (trimesh's vertex normals of the file's mesh)

    player = GlbPlayer(r.content)
    prim = player.doc.meshes[0].primitives[0]
    written = player.accessor(prim.indices).reshape(-1, 3)
    normal = player.accessor(prim.attributes.NORMAL)[written]  # (F, 3, 3) per corner
    theirs = trimesh.Trimesh(v, f, process=False).vertex_normals[f]
    agree = np.einsum("fkc,fkc->fk", normal, theirs)
    assert np.median(agree) > 0.95 and (agree > 0).mean() > 0.95, np.percentile(agree, [5, 50])
    assert len(GlbPlayer(r.content).accessor(
        GlbPlayer(r.content).doc.meshes[0].primitives[0].attributes.POSITION)) > len(v)  # the seam's copies
    rig = http.post("/v1/outfits/rig", files={"mesh": ("shirt.obj", data)}, headers={"Accept": NPZ})
    outfit_id = str(decode_npz(rig.content)["outfit_id"])
    a = http.post("/v1/outfits/animate", json={"outfit_id": outfit_id, "motion": {"clip": "walk"}, "refine": True},
                  headers={"Accept": GLB})
    assert a.status_code == 200, a.text[:300]
    assert validate(a.content)["errors"] == 0
    _same_corners(a.content, v, f, uv)
    # the same geometry without texture coordinates is another outfit, and its GLB has none (as before)
    plain = http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist()}, headers={"Accept": NPZ})
    assert str(decode_npz(plain.content)["outfit_id"]) != outfit_id
    g = http.post("/v1/outfits/animate", json={"outfit_id": str(decode_npz(plain.content)["outfit_id"]),
                                               "motion": {"clip": "walk"}}, headers={"Accept": GLB})
    assert GlbPlayer(g.content).doc.meshes[0].primitives[0].attributes.TEXCOORD_0 is None
    # and its rig (weights, blend shapes) is the one of the textured upload: UVs do not change the rig
    np.testing.assert_array_equal(decode_npz(plain.content)["blend_shapes"], decode_npz(rig.content)["blend_shapes"])


def test_a_glbs_texcoords_come_back(http, textured):
    import trimesh

    _, v, f, uv = textured
    per_vertex = np.zeros((len(v), 2), np.float32)
    per_vertex[f.reshape(-1)] = uv.reshape(-1, 2)  # one UV per vertex (a GLB's own layout): the last corner's
    mesh = trimesh.Trimesh(v, f, process=False, visual=trimesh.visual.TextureVisuals(uv=per_vertex))
    r = http.post("/v1/outfits/rig", files={"mesh": ("shirt.glb", mesh.export(file_type="glb"))},
                  headers={"Accept": GLB})
    assert r.status_code == 200, r.text[:300]
    _same_corners(r.content, v, f, per_vertex[f])


@pytest.mark.skipif(not (EXTERNAL / "ncsim_arcsim_tshirt_no_sleeves.obj").exists(), reason="../shared/data absent")
def test_a_real_garments_uvs_survive_fit_and_rig(http):
    """The ArcSim sleeveless top (Meshlab's OBJ: mtllib, vt, vn) fitted as OBJ, then rigged: its UVs are the
    file's, corner for corner."""
    from drape.geometry.mesh_io import obj_uv_corners

    data = (EXTERNAL / "ncsim_arcsim_tshirt_no_sleeves.obj").read_bytes()
    fitted = http.post("/v1/outfits/fit", files={"mesh": ("top.obj", data)}, headers={"Accept": "model/obj"})
    assert fitted.status_code == 200, fitted.text[:300]
    r = http.post("/v1/outfits/rig", files={"mesh": ("top.obj", fitted.content)}, headers={"Accept": GLB})
    assert r.status_code == 200, r.text[:300]
    doc = http.post("/v1/outfits/fit", files={"mesh": ("top.obj", data)}).json()
    f = np.asarray(doc["faces"])
    uv = obj_uv_corners(data, f)
    assert uv is not None and uv.shape == (len(f), 3, 2)
    _same_corners(r.content, np.asarray(doc["vertices"]), f, uv)
    assert json.loads(fitted.text.splitlines()[0][len("# drape fit report: "):])["inside_after"] <= 0.001
    assert io.BytesIO(r.content).getbuffer().nbytes > 0


def test_uvs_left_out_are_said(http, textured):
    """A GLB whose meshes carry texture coordinates on one of two meshes (trimesh then reads none), and an OBJ
    whose faces do not all name a `vt`: 200, no TEXCOORD_0 in the rig's GLB, and a Drape-Warnings sentence."""
    import trimesh

    data, v, f, uv = textured
    per_vertex = np.zeros((len(v), 2), np.float32)
    per_vertex[f.reshape(-1)] = uv.reshape(-1, 2)
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.Trimesh(v, f, process=False, visual=trimesh.visual.TextureVisuals(uv=per_vertex)),
                       node_name="with_uv")
    scene.add_geometry(trimesh.Trimesh(v + [0.0, 0.0, 0.01], f, process=False), node_name="without")
    import re

    no_vt = re.sub(rb"(?m)^f ([^\n]*)$", lambda m: b"f " + re.sub(rb"/\d+", b"", m.group(1)), data, count=1)
    assert no_vt != data
    for name, body in (("two.glb", scene.export(file_type="glb")), ("cut.obj", no_vt)):
        r = http.post("/v1/outfits/rig", files={"mesh": (name, body)}, headers={"Accept": GLB})
        assert r.status_code == 200, (name, r.text[:300])
        assert GlbPlayer(r.content).doc.meshes[0].primitives[0].attributes.TEXCOORD_0 is None, name
        assert "texture coordinates" in r.headers.get("Drape-Warnings", ""), (name, r.headers)
