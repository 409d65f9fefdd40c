"""Blender's side of `bench.blender_check`: run by the bpy venv, never imported by drape's.

Usage: .venv-blender/bin/python bench/blender_eval.py DIR

DIR holds `cases.json` (written by bench/blender_check.py: per case a name, the fps and the frames to
evaluate) and, per case, `<name>.glb`, `<name>.pc2` and `<name>.npz` (drape's reference: vertices
(T, N, 3), faces (F, 3)). Per case this writes `<name>.blender.npz`: `glb` (len(frames), N, 3), the
evaluated "outfit" mesh of the imported GLB, back in glTF axes (+Y up) and drape's vertex order;
`pc2` (len(frames), N, 3), a mesh built from the reference's frame 0 and faces deformed by a Mesh
Cache modifier reading the PC2 as-is; and `info` (a JSON string) with what was found on the way:
Blender's vertex count and how vertices were matched, the pose-key range, whether the importer
stored any key value other than the GLB's (import-time clamping), the shape-key values Blender
evaluated at each frame against the GLB's weights at that key (the frame mapping, and clamping at
evaluation time), the rest-pose match.

GLB import: factory-empty scene; scene fps (and fps_base 1) set to the clip's before the import, since
the importer times keys by the scene fps; the importer's defaults otherwise. The importer puts the
weights animation in the active action of the shape keys (key time x fps -> Blender frame, so glTF key
t is Blender frame t; the stashed NLA copies are muted), and widens each key's slider range only to its
value at the first key; Blender then clamps animated shape-key values to [slider_min, slider_max] when
it evaluates them, so every key's range is widened to cover all its values (Blender allows -10..10).
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import bpy
import numpy as np

_COMPONENTS = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
SLIDER_LIMIT = 10.0  # Blender's hard bound on slider_min / slider_max


def read_glb(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    magic, _, _ = struct.unpack_from("<4sII", data)
    assert magic == b"glTF", path
    n, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON"
    doc = json.loads(data[20:20 + n])
    m, kind = struct.unpack_from("<I4s", data, 20 + n)
    assert kind == b"BIN\0"
    return doc, data[28 + n:28 + n + m]


def accessor(doc: dict, blob: bytes, index: int) -> np.ndarray:
    """A dense (non-sparse, tightly packed) accessor -> (count, width) array."""
    a = doc["accessors"][index]
    assert "sparse" not in a
    view = doc["bufferViews"][a["bufferView"]]
    assert view.get("byteStride") in (None, 0)
    dtype, width = _COMPONENTS[a["componentType"]], _WIDTH[a["type"]]
    start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
    return np.frombuffer(blob, dtype=dtype, count=a["count"] * width, offset=start).reshape(a["count"], width)


def glb_weights(doc: dict, blob: bytes, mesh_name: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The morph-weight channel of the mesh node `mesh_name` -> (times (T,), weights (T, M), target names)."""
    node = next(i for i, n in enumerate(doc["nodes"]) if n.get("name") == mesh_name)
    names = doc["meshes"][doc["nodes"][node]["mesh"]]["extras"]["targetNames"]
    for anim in doc.get("animations", []):
        for ch in anim["channels"]:
            if ch["target"].get("node") == node and ch["target"]["path"] == "weights":
                s = anim["samplers"][ch["sampler"]]
                assert s.get("interpolation", "LINEAR") == "LINEAR"
                times = accessor(doc, blob, s["input"])[:, 0]
                return times, accessor(doc, blob, s["output"]).reshape(len(times), len(names)), names
    raise LookupError(f"no weights animation on {mesh_name}")


def glb_mesh(doc: dict, blob: bytes, mesh_name: str) -> tuple[np.ndarray, np.ndarray]:
    """The rest POSITION (N, 3) and triangles (F, 3) of the mesh node `mesh_name` (one primitive)."""
    node = next(n for n in doc["nodes"] if n.get("name") == mesh_name)
    (prim,) = doc["meshes"][node["mesh"]]["primitives"]
    faces = accessor(doc, blob, prim["indices"]).reshape(-1, 3).astype(np.int64)
    return accessor(doc, blob, prim["attributes"]["POSITION"]).astype(np.float64), faces


def evaluated_positions(obj: bpy.types.Object) -> np.ndarray:
    """The object's evaluated mesh (modifiers, shape keys, armature) in world space -> (n, 3) float64."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    co = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    m = np.array(ev.matrix_world, dtype=np.float64)
    co64 = co.reshape(-1, 3).astype(np.float64)
    return co64 @ m[:3, :3].T + m[:3, 3]


def blender_to_gltf(p: np.ndarray) -> np.ndarray:
    """The importer maps glTF (x, y, z) to Blender (x, -z, y); this is the inverse."""
    return np.stack([p[:, 0], p[:, 2], -p[:, 1]], axis=1)


def match_vertices(blender_rest: np.ndarray, ref_rest: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, str]:
    """Blender vertex index per drape vertex (-1 where Blender has none) and how it was found."""
    n = len(ref_rest)
    if len(blender_rest) == n:
        return np.arange(n), "import order (same count)"
    used = np.unique(faces)  # the importer keeps the referenced vertices, in index order
    if len(blender_rest) == len(used):
        idx = np.full(n, -1)
        idx[used] = np.arange(len(used))
        return idx, "import order of the vertices faces use"
    # nearest rest position, in blocks (numpy only)
    idx = np.empty(n, dtype=np.int64)
    for s in range(0, n, 512):
        d = ((ref_rest[s:s + 512, None, :] - blender_rest[None, :, :]) ** 2).sum(axis=2)
        idx[s:s + 512] = d.argmin(axis=1)
    return idx, "nearest rest position"


def eval_glb(path: Path, case: dict, ref: dict, info: dict) -> np.ndarray:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = int(round(case["fps"])), 1.0
    info["scene_frame_start"] = scene.frame_start
    bpy.ops.import_scene.gltf(filepath=str(path))
    # the node's weights are animated, so the importer leaves an Empty "outfit" at the node and puts
    # the skinned mesh in a new child of the armature ("outfit.001"): find it by its mesh's name
    (obj,) = [o for o in bpy.data.objects if o.type == "MESH" and o.data.name == "outfit"]
    info["outfit_object"] = obj.name
    doc, blob = read_glb(path)
    times, weights, names = glb_weights(doc, blob, "outfit")
    info["glb_key_frames"] = [float(times[0] * case["fps"]), float(times[-1] * case["fps"])]
    psd = [i for i, nm in enumerate(names) if nm.startswith("psd_")]
    info["pose_keys"] = len(psd)
    info["correction_keys"] = len(names) - len(psd)
    info["pose_key_range"] = [float(weights[:, psd].min()), float(weights[:, psd].max())] if psd else None
    info["pose_key_values_outside_0_1"] = int(((weights[:, psd] < 0) | (weights[:, psd] > 1)).sum())
    info["pose_key_values_beyond_10"] = int((np.abs(weights) > SLIDER_LIMIT).sum())

    keys = obj.data.shape_keys
    blocks = keys.key_blocks
    # what the importer stored, before anything is touched: its keyframe values against the GLB's
    action = keys.animation_data.action if keys.animation_data else None
    info["shape_key_action"] = action.name if action else None
    stored_diff, slider_before = 0.0, [np.inf, -np.inf]
    fcurves = {}
    if action is not None:
        for bag in (cb for layer in action.layers for strip in layer.strips for cb in strip.channelbags):
            for fc in bag.fcurves:
                fcurves[fc.data_path] = fc
    for m, name in enumerate(names):
        kb = blocks[name]
        slider_before = [min(slider_before[0], kb.slider_min), max(slider_before[1], kb.slider_max)]
        fc = fcurves.get(f'key_blocks["{name}"].value')
        if fc is None:
            stored_diff = np.inf
            continue
        co = np.empty(2 * len(fc.keyframe_points), dtype=np.float32)
        fc.keyframe_points.foreach_get("co", co)
        stored_diff = max(stored_diff, float(np.abs(co[1::2] - weights[:, m]).max()))
        info.setdefault("fcurve_frames", [float(co[0]), float(co[-2])])
    info["importer_slider_range"] = slider_before
    info["stored_key_values_max_diff"] = stored_diff  # > 0: clamped (or lost) at import time
    for m, name in enumerate(names):
        kb = blocks[name]
        kb.slider_min = max(-SLIDER_LIMIT, min(0.0, float(weights[:, m].min())))
        kb.slider_max = min(SLIDER_LIMIT, max(1.0, float(weights[:, m].max())))

    # the vertex matching: Blender's basis positions (world space, glTF axes) against the GLB's own
    arm_mods = [md for md in obj.modifiers if md.type == "ARMATURE"]
    co = np.empty(len(obj.data.vertices) * 3, dtype=np.float32)
    obj.data.vertices.foreach_get("co", co)
    mw = np.array(obj.matrix_world, dtype=np.float64)
    rest = blender_to_gltf(co.reshape(-1, 3).astype(np.float64) @ mw[:3, :3].T + mw[:3, 3])
    glb_rest, glb_faces = glb_mesh(doc, blob, "outfit")
    node = next(n for n in doc["nodes"] if n.get("name") == "outfit")
    info["joint_sets"] = sum(k.startswith("JOINTS_") for k in doc["meshes"][node["mesh"]]["primitives"][0]["attributes"])
    assert len(glb_rest) == len(ref["frame0"]), (len(glb_rest), len(ref["frame0"]))
    idx, how = match_vertices(rest, glb_rest, glb_faces)
    info["blender_vertices"] = len(rest)
    info["vertex_match"] = how
    ok = idx >= 0
    info["rest_max_mm"] = float(np.linalg.norm(rest[idx[ok]] - glb_rest[ok], axis=1).max() * 1e3)
    info["armature_modifiers"] = len(arm_mods)

    out = np.full((len(case["frames"]), len(glb_rest), 3), np.nan)
    info["evaluated_key_diff"] = []
    for i, f in enumerate(case["frames"]):
        scene.frame_set(int(f))
        p = blender_to_gltf(evaluated_positions(obj))
        out[i, ok] = p[idx[ok]]
        have = np.array([blocks[nm].value for nm in names])  # the values Blender evaluated at this frame
        info["evaluated_key_diff"].append(float(np.abs(have - weights[int(f)]).max()))
    return out


def clamp_probe(path: Path, fps: float) -> dict:
    """Does Blender clamp animated shape-key values to the slider range? Key psd_0 of the imported GLB
    re-keyed to 2.5 at frame 5 and -1.5 at frame 6, evaluated with the importer's slider range, then
    with -10..10."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = int(round(fps)), 1.0
    bpy.ops.import_scene.gltf(filepath=str(path))
    (obj,) = [o for o in bpy.data.objects if o.type == "MESH" and o.data.name == "outfit"]
    keys = obj.data.shape_keys
    action = keys.animation_data.action
    (fc,) = [fc for layer in action.layers for strip in layer.strips for bag in strip.channelbags
             for fc in bag.fcurves if fc.data_path == 'key_blocks["psd_0"].value']
    fc.keyframe_points[5].co[1], fc.keyframe_points[6].co[1] = 2.5, -1.5
    fc.update()
    kb = keys.key_blocks["psd_0"]
    out: dict = {"keyed": [2.5, -1.5], "importer_slider": [kb.slider_min, kb.slider_max]}
    for label in ("with_importer_slider", "with_slider_-10_10"):
        got = []
        for f in (5, 6):
            scene.frame_set(f)
            got.append(kb.value)
        out[label] = got
        kb.slider_min, kb.slider_max = -SLIDER_LIMIT, SLIDER_LIMIT
    return out


def eval_pc2(path: Path, case: dict, ref: dict, info: dict) -> np.ndarray:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = int(round(case["fps"])), 1.0
    v0, faces = ref["frame0"], ref["faces"]
    mesh = bpy.data.meshes.new("pc2")
    mesh.from_pydata(v0.tolist(), [], faces.tolist())
    mesh.update()
    obj = bpy.data.objects.new("pc2", mesh)
    scene.collection.objects.link(obj)
    md = obj.modifiers.new("cache", "MESH_CACHE")
    md.cache_format = "PC2"
    md.filepath = str(path.resolve())
    md.frame_start = 0.0  # the cache's sample 0 plays at scene frame 0
    md.frame_scale = 1.0
    md.play_mode = "SCENE"
    md.time_mode = "FRAME"
    md.deform_mode = "OVERWRITE"
    md.interpolation = "LINEAR"
    md.forward_axis, md.up_axis = "POS_Y", "POS_Z"  # identity: the data read as stored
    md.flip_axis = (False, False, False)
    md.factor = 1.0
    info["pc2_vertices"] = len(mesh.vertices)
    out = np.empty((len(case["frames"]), len(v0), 3))
    for i, f in enumerate(case["frames"]):
        scene.frame_set(int(f))
        out[i] = evaluated_positions(obj)
    return out


def main() -> None:
    folder = Path(sys.argv[1])
    cases = json.loads((folder / "cases.json").read_text())["cases"]
    probe = clamp_probe(folder / f"{cases[0]['name']}.glb", cases[0]["fps"])
    (folder / "clamp_probe.json").write_text(json.dumps(probe))
    print("clamp probe", json.dumps(probe), flush=True)
    for case in cases:
        name = case["name"]
        with np.load(folder / f"{name}.npz") as z:
            verts = z["vertices"]
            ref = {"faces": z["faces"].astype(np.int64), "frame0": verts[0].astype(np.float64)}
        info: dict = {"bpy": bpy.app.version_string}
        glb = eval_glb(folder / f"{name}.glb", case, ref, info)
        pc2 = eval_pc2(folder / f"{name}.pc2", case, ref, info)
        np.savez(folder / f"{name}.blender.npz", glb=glb, pc2=pc2, frames=np.array(case["frames"]),
                 info=np.array(json.dumps(info)))
        print(name, json.dumps(info), flush=True)


if __name__ == "__main__":
    main()
