"""Multi-part meshes answer with their parts, and UV seams stay closed (issue 20, item 8): an OBJ with two
objects, each cut by a UV seam (coincident vertex copies), rigged through the API and the client."""

import numpy as np
import pytest

import drape
from drape.assets.outfits import generate_outfit
from drape.geometry.mesh import weld


def obj_with_parts(pieces: list[tuple[str, np.ndarray, np.ndarray]]) -> bytes:
    """An OBJ with one `o` object per (name, vertices, faces), in this order (face indices file-global)."""
    out, base = [], 0
    for name, v, f in pieces:
        out.append(f"o {name}")
        out += [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in v]
        out += [f"f {a + base + 1} {b + base + 1} {c + base + 1}" for a, b, c in f]
        base += len(v)
    return ("\n".join(out) + "\n").encode()


def with_seam(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The faces right of x = 0 use copies of the vertices they share with the left (a UV cut)."""
    right = v[f].mean(axis=1)[:, 0] > 0
    copied = np.intersect1d(np.unique(f[right]), np.unique(f[~right]))
    remap = np.arange(len(v))
    remap[copied] = len(v) + np.arange(len(copied))
    f2 = f.copy()
    f2[right] = remap[f[right]]
    return np.concatenate([v, v[copied]]), f2, copied


@pytest.fixture(scope="module")
def upload():
    shirt = generate_outfit("tshirt", vertices=600, seed=31)
    pants = generate_outfit("trousers", vertices=600, seed=32)
    sv, sf, s_copied = with_seam(shirt.vertices, shirt.faces)
    pv, pf, p_copied = with_seam(pants.vertices, pants.faces)
    data = obj_with_parts([("pants", pv, pf), ("shirt", sv, sf)])  # the file's order, not alphabetical
    pairs = [(len(pants.vertices) + k, int(i)) for k, i in enumerate(p_copied)]
    pairs += [(len(pv) + len(shirt.vertices) + k, len(pv) + int(i)) for k, i in enumerate(s_copied)]
    return data, (len(pv), len(sv)), np.array(pairs)


def test_rig_names_the_parts_in_file_order(http, upload):
    data, (n_pants, n_shirt), _ = upload
    r = http.post("/v1/outfits/rig", files={"mesh": ("outfit.obj", data)})
    assert r.status_code == 200, r.text[:300]
    assert r.json()["parts"] == [{"name": "pants", "start": 0, "stop": n_pants},
                                 {"name": "shirt", "start": n_pants, "stop": n_pants + n_shirt}]
    assert r.json()["num_vertices"] == n_pants + n_shirt


def test_a_glbs_meshes_are_the_rigs_parts_named_by_their_nodes(http):
    """A GLB with two placed meshes (a shirt and trousers): the rig answers each as a part named by its node,
    in the order the vertices were read (trimesh's, which the answer's vertex ranges follow), each range holding
    that garment's vertices where the file placed them (GLB uploads reported no parts)."""
    import trimesh

    shirt = generate_outfit("tshirt", vertices=600, seed=31)
    pants = generate_outfit("trousers", vertices=600, seed=32)
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.Trimesh(shirt.vertices, shirt.faces, process=False), node_name="shirt_node",
                       geom_name="shirt_mesh")
    scene.add_geometry(trimesh.Trimesh(pants.vertices - [0.0, 0.02, 0.0], pants.faces, process=False),
                       node_name="pants_node", geom_name="pants_mesh", transform=trimesh.transformations.
                       translation_matrix([0.0, 0.02, 0.0]))
    data = scene.export(file_type="glb")
    r = http.post("/v1/outfits/rig", files={"mesh": ("outfit.glb", data)}, headers={"Accept": "application/x-npz"})
    assert r.status_code == 200, r.text[:300]
    doc = http.post("/v1/outfits/rig", files={"mesh": ("outfit.glb", data)}).json()
    parts = doc["parts"]
    assert sorted(p["name"] for p in parts) == ["pants_node", "shirt_node"], parts
    assert parts[0]["start"] == 0 and parts[0]["stop"] == parts[1]["start"] and parts[1]["stop"] == doc["num_vertices"]
    sizes = {p["name"]: p["stop"] - p["start"] for p in parts}
    assert sizes == {"shirt_node": len(shirt.vertices), "pants_node": len(pants.vertices)}
    from drape.service.uploads import mesh_file

    read = mesh_file(data, "outfit.glb", max_vertices=10**5, max_faces=10**5)
    garment = {"shirt_node": shirt.vertices, "pants_node": pants.vertices}  # the node moved the trousers back
    for p in parts:
        np.testing.assert_allclose(read.vertices[p["start"]:p["stop"]], garment[p["name"]], atol=1e-6)


def test_seams_stay_closed_through_rig_and_animate(server_url, upload, tmp_path):
    data, _, pairs = upload
    path = tmp_path / "outfit.obj"
    path.write_bytes(data)
    with drape.Client(server_url) as client:
        rig = client.rig(path)
        frames = client.animate(outfit_id=rig.outfit_id, motion="walk", refine=True)
    assert rig.parts is not None and [p["name"] for p in rig.parts] == ["pants", "shirt"]
    a, b = pairs[:, 0], pairs[:, 1]
    np.testing.assert_array_equal(rig.skinning_weights[a], rig.skinning_weights[b])
    np.testing.assert_array_equal(rig.blend_shapes[:, a], rig.blend_shapes[:, b])
    assert np.abs(frames[:, a] - frames[:, b]).max() == 0.0
    # the seams are real: without welding these copies are separate vertices of the mesh
    _, _, group = weld(np.concatenate([frames[0]]), np.zeros((0, 3), dtype=np.int64))
    assert len(np.unique(group)) == frames.shape[1] - len(pairs)


def test_obj_parts_reads_objects_or_groups_and_none_for_one_part():
    from drape.geometry.mesh_io import obj_parts

    two = b"o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf 4 5 6\n"
    assert obj_parts(two, "x.obj", 6) == [{"name": "a", "start": 0, "stop": 3}, {"name": "b", "start": 3, "stop": 6}]
    assert obj_parts(two.replace(b"o ", b"g "), "x.OBJ", 6)[1]["name"] == "b"
    assert obj_parts(b"o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "x.obj", 3) is None
    assert obj_parts(two, "x.obj", 7) is None  # read otherwise than counted: no parts rather than wrong ones
    assert obj_parts(two, "x.ply", 6) is None
