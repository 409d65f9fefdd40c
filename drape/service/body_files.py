"""A user's skinned body read from a GLB (or a .gltf with embedded buffers), for POST /v1/bodies.

`body_from_glb(data, joint_map=..., max_vertices=..., max_faces=...)` -> the body contract's arrays,
joints and weight columns in SMPL order (`drape.geometry.skeleton.JOINT_NAMES`):

* "vertices" (V, 3) float64 m: the rest shape, as the file shows it;
* "faces" (F, 3) int64, indices into vertices;
* "weights" (V, 24) float64, rows summing to 1;
* "joints" (24, 3) float64 m: the rest joint positions.

The file's structure is checked by `drape.service.uploads.gltf_tree_and_reader` (GLB chunks, JSON
bounds, buffers, bufferViews and accessors within the bytes sent). The body is the first node with
both a `mesh` and a `skin` whose name holds "body" (case-insensitively), else the first node with both
(so a garment skinned beside the body, as in drape's rig GLB, is not read as the body); its mesh's primitives (triangle lists, indices optional) are
concatenated; POSITION and JOINTS_0 / WEIGHTS_0 are required, JOINTS_1..3 / WEIGHTS_1..3 are read
where present (WEIGHTS float or normalised unsigned byte / short, JOINTS unsigned byte / short, both
indexing `skin.joints`).

Rest pose = the file's current node pose: every node's world matrix from the hierarchy (matrix or
translation / rotation (quaternion x, y, z, w) / scale), the vertices linearly blend-skinned with
world(joint) @ inverseBindMatrix(joint) (identity without inverseBindMatrices), so an armature
not at its bind pose still gives the shape it shows; a joint's rest position is the translation of
world(joint).

Joint names (the skin joints' node names) map to SMPL names by `joint_map` (file name -> SMPL name)
when one is given, else by name: exactly, or SMPL-FBX style, case-insensitively, after dropping a
"prefix:" and one of the prefixes "m_avg_", "f_avg_", "smpl_", with "L_" / "R_" read as "left_" /
"right_" ("m_avg_L_Hip" -> left_hip). A skin joint mapping to no SMPL joint gives its weight to its
nearest ancestor node that does. Weights must be finite, non-negative and sum to 1 within
`WEIGHT_SUM_TOLERANCE` per vertex; they are renormalised.

Errors name the field "body_file": `LimitExceeded` (413) when the mesh has more vertices or faces
than allowed (checked before any array is read), `MalformedInput` (400) for a file that is not a
readable glTF, `InvalidInput` (422) for a readable file drape cannot use as a body.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NoReturn

import numpy as np

from drape.geometry.skeleton import JOINT_INDEX, JOINT_NAMES
from drape.service.errors import InvalidInput, LimitExceeded, MalformedInput, quoted
from drape.service.uploads import gltf_tree_and_reader

FIELD = "body_file"
MAX_SKIN_SETS = 4  # JOINTS_0..3 / WEIGHTS_0..3: up to 16 influences per vertex
WEIGHT_SUM_TOLERANCE = 1e-2
SMPL_PREFIXES = ("m_avg_", "f_avg_", "smpl_")

_FLOAT, _U8, _U16, _U32 = 5126, 5121, 5123, 5125


def body_from_glb(data: bytes, *, joint_map: dict[str, str] | None, max_vertices: int,
                  max_faces: int) -> dict[str, np.ndarray]:
    """A skinned GLB (or .gltf with embedded base64 buffers) -> the body contract's arrays, in SMPL
    joint order: {"vertices": (V, 3) float64 m, "faces": (F, 3) int64, "weights": (V, 24) float64
    rows summing to 1, "joints": (24, 3) float64 m (rest joint positions)}.

    joint_map: file joint name -> SMPL joint name (None or empty: match the names); see the module
    docstring for the rules and the errors.
    """
    head = data[:64].lstrip()
    if data[:4] == b"glTF":
        suffix = ".glb"
    elif head.startswith((b"{", b"\xef\xbb\xbf{")):
        suffix = ".gltf"
    else:
        raise MalformedInput("not a GLB (the first 4 bytes are not 'glTF') nor a glTF JSON file",
                             FIELD)
    tree, read = gltf_tree_and_reader(data, suffix, field=FIELD)
    nodes = _list(tree, "nodes")
    body = _body_node(nodes)
    if body is None:
        raise InvalidInput("the file has no skinned mesh: no node has both a mesh and a skin; "
                           "export the body with its armature (skin weights) included", FIELD)
    meshes, skins = _list(tree, "meshes"), _list(tree, "skins")
    mesh = meshes[_index(nodes[body]["mesh"], len(meshes), f"nodes[{body}].mesh")]
    skin = skins[_index(nodes[body]["skin"], len(skins), f"nodes[{body}].skin")]
    mesh_at = f"meshes[{nodes[body]['mesh']}]"
    primitives = _primitives(tree, mesh, mesh_at, max_vertices, max_faces)

    parents = _parents(nodes)
    joint_nodes = _skin_joints(skin, len(nodes))
    world = _world_matrices(nodes, parents, joint_nodes)
    ibm = _inverse_binds(tree, read, skin, len(joint_nodes))
    skinning = np.stack([world[n] for n in joint_nodes]) @ ibm  # (J, 4, 4)
    if not np.isfinite(skinning).all():
        _invalid("the skin's joint matrices (node transforms and inverse bind matrices) are not "
                 "all finite")

    positions, faces, joints, weights = _read_primitives(read, primitives, mesh_at)
    names = [n.get("name") if isinstance(n.get("name"), str) else None
             for n in (nodes[k] for k in joint_nodes)]
    smpl = _smpl_indices(names, joint_map)
    target = _weight_targets(smpl, joint_nodes, parents)
    weights = _checked_weights(weights, joints, len(joint_nodes))

    safe = np.where(weights > 0, joints, 0)
    blend = np.zeros((len(positions), 3, 4))
    for s in range(weights.shape[1]):
        blend += weights[:, s, None, None] * skinning[safe[:, s], :3, :]
    vertices = np.einsum("vij,vj->vi", blend[:, :, :3], positions) + blend[:, :, 3]

    to_smpl = target[safe]
    lost = ((to_smpl < 0) & (weights > 0)).any(axis=1)
    if lost.any():
        orphans = sorted({str(names[k]) for k in np.unique(safe[(to_smpl < 0) & (weights > 0)])})
        _invalid(f"{int(lost.sum())} vertices carry weight on joints that map to no SMPL joint and "
                 f"have no mapped ancestor: {quoted(orphans)}; give joint_map")
    smpl_weights = np.zeros((len(positions), len(JOINT_NAMES)))
    rows = np.broadcast_to(np.arange(len(positions))[:, None], to_smpl.shape)
    np.add.at(smpl_weights, (rows, np.maximum(to_smpl, 0)), np.where(to_smpl >= 0, weights, 0.0))
    smpl_weights /= smpl_weights.sum(axis=1, keepdims=True)

    by_smpl = {j: joint_nodes[k] for k, j in enumerate(smpl) if j >= 0}
    rest_joints = np.stack([world[by_smpl[j]][:3, 3] for j in range(len(JOINT_NAMES))])
    if not (np.isfinite(vertices).all() and np.isfinite(rest_joints).all()):
        _invalid("the skinned rest pose is not finite (extreme node transforms)")
    return {"vertices": vertices, "faces": faces, "weights": smpl_weights, "joints": rest_joints}


# -------------------------------------------------------------------------------- declarations

def _invalid(detail: str, field: str = FIELD) -> NoReturn:
    raise InvalidInput(detail, field)


def _bad(detail: str) -> NoReturn:
    raise MalformedInput(detail, FIELD)


def _list(tree: dict[str, Any], key: str) -> list[dict[str, Any]]:
    value = tree.get(key, [])
    if not isinstance(value, list) or not all(isinstance(x, dict) for x in value):
        _bad(f"glTF '{key}' must be a list of objects")
    return value


def _index(value: Any, size: int, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < size:
        _bad(f"{where} must be an index below {size}, got {quoted(value, 40)}")
    return value


def _accessor(tree: dict[str, Any], value: Any, where: str, kinds: tuple[str, ...],
              components: tuple[int, ...]) -> tuple[int, int]:
    """An accessor index checked for its type and component type -> (index, count)."""
    accessors = tree.get("accessors", [])  # checked to be a list of valid accessors
    index = _index(value, len(accessors), where)
    a = accessors[index]
    if a["type"] not in kinds or a["componentType"] not in components:
        _invalid(f"{where}: accessors[{index}] is {a['type']} of componentType "
                 f"{a['componentType']}; expected {'/'.join(kinds)} of {components}")
    return index, a["count"]


@dataclass(frozen=True)
class _Primitive:
    where: str
    position: int  # accessor indices
    count: int  # vertices
    indices: int | None
    sets: list[tuple[int, int]]  # (JOINTS_n, WEIGHTS_n)


def _primitives(tree: dict[str, Any], mesh: dict[str, Any], mesh_at: str, max_vertices: int,
                max_faces: int) -> list[_Primitive]:
    """The skinned mesh's primitives checked and counted against the limits (nothing read)."""
    primitives = mesh.get("primitives")
    if not isinstance(primitives, list) or not primitives or not all(
            isinstance(p, dict) for p in primitives):
        _bad(f"{mesh_at}.primitives must be a non-empty list of objects")
    out = []
    vertices = faces = 0
    for j, p in enumerate(primitives):
        where = f"{mesh_at}.primitives[{j}]"
        extensions = p.get("extensions")
        if isinstance(extensions, dict) and "KHR_draco_mesh_compression" in extensions:
            _invalid(f"{where} is Draco-compressed, which is not supported: export without it")
        mode = p.get("mode", 4)
        if mode != 4 or isinstance(mode, bool):
            _invalid(f"{where} has mode {quoted(mode, 40)}: only triangle lists (mode 4) are "
                     "supported")
        attributes = p.get("attributes")
        if not isinstance(attributes, dict) or "POSITION" not in attributes:
            _bad(f"{where} has no POSITION attribute")
        position, count = _accessor(tree, attributes["POSITION"], f"{where}.attributes.POSITION",
                                    ("VEC3",), (_FLOAT,))
        sets = []
        for s in range(MAX_SKIN_SETS + 1):
            has_joints, has_weights = f"JOINTS_{s}" in attributes, f"WEIGHTS_{s}" in attributes
            if not has_joints and not has_weights:
                if s == 0:
                    _invalid(f"{where} has no JOINTS_0 / WEIGHTS_0: the mesh carries no skin "
                             "weights")
                break
            if s == MAX_SKIN_SETS:
                _invalid(f"{where} has more than {MAX_SKIN_SETS} JOINTS_n / WEIGHTS_n sets "
                         f"(at most {4 * MAX_SKIN_SETS} influences per vertex are supported)")
            if has_joints != has_weights:
                _bad(f"{where} has {'JOINTS' if has_joints else 'WEIGHTS'}_{s} without its "
                     f"{'WEIGHTS' if has_joints else 'JOINTS'}_{s}")
            ji, jn = _accessor(tree, attributes[f"JOINTS_{s}"], f"{where}.attributes.JOINTS_{s}",
                               ("VEC4",), (_U8, _U16))
            wi, wn = _accessor(tree, attributes[f"WEIGHTS_{s}"],
                               f"{where}.attributes.WEIGHTS_{s}", ("VEC4",), (_FLOAT, _U8, _U16))
            if jn != count or wn != count:
                _bad(f"{where}: JOINTS_{s} ({jn}) and WEIGHTS_{s} ({wn}) must have one element "
                     f"per vertex ({count})")
            sets.append((ji, wi))
        indices = None
        corners = count
        if p.get("indices") is not None:
            indices, corners = _accessor(tree, p["indices"], f"{where}.indices", ("SCALAR",),
                                         (_U8, _U16, _U32))
        if corners % 3:
            _bad(f"{where} has {corners} triangle corners, not a multiple of 3")
        vertices += count
        faces += corners // 3
        if vertices > max_vertices:
            raise LimitExceeded(f"the skinned mesh has at least {vertices} vertices, over the "
                                f"limit of {max_vertices}", FIELD)
        if faces > max_faces:
            raise LimitExceeded(f"the skinned mesh has at least {faces} triangles, over the limit "
                                f"of {max_faces}", FIELD)
        out.append(_Primitive(where, position, count, indices, sets))
    return out


def _parents(nodes: list[dict[str, Any]]) -> list[int]:
    """Each node's parent (-1 for a root); a node with two parents is refused."""
    parents = [-1] * len(nodes)
    for i, n in enumerate(nodes):
        children = n.get("children", [])
        if not isinstance(children, list):
            _bad(f"nodes[{i}].children must be a list")
        for c in children:
            c = _index(c, len(nodes), f"nodes[{i}].children[]")
            if parents[c] >= 0 or c == i:
                _bad(f"nodes[{c}] has more than one parent (the nodes must form trees)")
            parents[c] = i
    return parents


def _body_node(nodes: list[dict[str, Any]]) -> int | None:
    """The node holding the body: of the nodes with a mesh and a skin, the first whose name says "body"
    (case-insensitively; a file of a garment and the body skinned to one armature, as drape's own rig GLB), else
    the first; None without one."""
    skinned = [i for i, n in enumerate(nodes) if isinstance(n, dict) and "mesh" in n and "skin" in n]
    named = [i for i in skinned if isinstance(nodes[i].get("name"), str) and "body" in nodes[i]["name"].lower()]
    chosen = named or skinned
    return chosen[0] if chosen else None


def _skin_joints(skin: dict[str, Any], num_nodes: int) -> list[int]:
    joints = skin.get("joints")
    if not isinstance(joints, list) or not joints:
        _bad("the body's skin has no joints list")
    out = [_index(j, num_nodes, "skin.joints[]") for j in joints]
    if len(set(out)) != len(out):
        _bad("the body's skin lists a node twice in its joints")
    return out


def _local(node: dict[str, Any], i: int) -> np.ndarray:
    """A node's local matrix (4, 4) from its matrix or its translation, rotation, scale."""

    def numbers(key: str, size: int, default: list[float]) -> np.ndarray:
        value = node.get(key, default)
        if (not isinstance(value, list) or len(value) != size or not all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in value)):
            _bad(f"nodes[{i}].{key} must be a list of {size} numbers")
        try:
            out = np.array(value, dtype=np.float64)
        except OverflowError:  # an integer past float64's range (JSON allows 10**400)
            _invalid(f"nodes[{i}].{key} is not finite")
        if not np.isfinite(out).all():
            _invalid(f"nodes[{i}].{key} is not finite")
        return out

    if "matrix" in node:
        return numbers("matrix", 16, []).reshape(4, 4).T  # glTF matrices are column-major
    t = numbers("translation", 3, [0.0, 0.0, 0.0])
    x, y, z, w = numbers("rotation", 4, [0.0, 0.0, 0.0, 1.0])
    s = numbers("scale", 3, [1.0, 1.0, 1.0])
    norm = float(np.sqrt(x * x + y * y + z * z + w * w))
    if not norm > 1e-6:
        _invalid(f"nodes[{i}].rotation is not a unit quaternion")
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = rot * s[None, :]
    m[:3, 3] = t
    return m


def _world_matrices(nodes: list[dict[str, Any]], parents: list[int],
                    wanted: list[int]) -> dict[int, np.ndarray]:
    """World matrices (4, 4) of the wanted nodes and their ancestors."""
    world: dict[int, np.ndarray] = {}
    for start in wanted:
        chain = []
        n = start
        while n >= 0 and n not in world:
            chain.append(n)
            if len(chain) > len(nodes):
                _bad("the node hierarchy has a cycle")
            n = parents[n]
        above = world[n] if n >= 0 else np.eye(4)
        for k in reversed(chain):
            above = world[k] = above @ _local(nodes[k], k)
    return world


def _inverse_binds(tree: dict[str, Any], read: Callable[[int], np.ndarray], skin: dict[str, Any],
                   num_joints: int) -> np.ndarray:
    if skin.get("inverseBindMatrices") is None:
        return np.tile(np.eye(4), (num_joints, 1, 1))
    index, count = _accessor(tree, skin["inverseBindMatrices"], "skin.inverseBindMatrices",
                             ("MAT4",), (_FLOAT,))
    if count < num_joints:
        _bad(f"the skin has {num_joints} joints but {count} inverse bind matrices")
    ibm = read(index)[:num_joints].astype(np.float64)
    if not np.isfinite(ibm).all():
        _invalid("the skin's inverse bind matrices are not all finite")
    return ibm


# ------------------------------------------------------------------------------------ arrays

def _read_primitives(read: Callable[[int], np.ndarray], primitives: list[_Primitive],
                     mesh_at: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """-> positions (V, 3) float64, faces (F, 3) int64, joints (V, 4S) int64, weights (V, 4S)."""
    width = 4 * max(len(p.sets) for p in primitives)
    positions, faces, joints, weights = [], [], [], []
    start = 0
    for p in primitives:
        pos = read(p.position).astype(np.float64)
        bad = ~np.isfinite(pos).all(axis=1)
        if bad.any():
            _invalid(f"{p.where}: {int(bad.sum())} vertex positions are not finite (NaN or "
                     "infinite)")
        if p.indices is None:
            tri = np.arange(p.count, dtype=np.int64)
        else:
            tri = read(p.indices).astype(np.int64)
            if tri.max() >= p.count:
                _invalid(f"{p.where}.indices refer to vertex {int(tri.max())}, beyond the "
                         f"primitive's {p.count} vertices")
        j = np.zeros((p.count, width), np.int64)
        w = np.zeros((p.count, width))
        for s, (ji, wi) in enumerate(p.sets):
            j[:, 4 * s:4 * s + 4] = read(ji)
            raw = read(wi)
            scale = float(np.iinfo(raw.dtype).max) if raw.dtype.kind == "u" else 1.0  # normalised
            w[:, 4 * s:4 * s + 4] = raw.astype(np.float64) / scale
        positions.append(pos)
        faces.append(tri.reshape(-1, 3) + start)
        joints.append(j)
        weights.append(w)
        start += p.count
    return (np.concatenate(positions), np.concatenate(faces), np.concatenate(joints),
            np.concatenate(weights))


def _checked_weights(weights: np.ndarray, joints: np.ndarray, num_joints: int) -> np.ndarray:
    """Finite, non-negative, on existing joints, summing to 1 within the tolerance -> renormalised."""
    bad = (~np.isfinite(weights) | (weights < 0)).any(axis=1)
    if bad.any():
        _invalid(f"{int(bad.sum())} vertices have negative or non-finite skin weights")
    beyond = ((joints >= num_joints) & (weights > 0)).any(axis=1)
    if beyond.any():
        _invalid(f"{int(beyond.sum())} vertices are weighted to joint indices beyond the skin's "
                 f"{num_joints} joints")
    sums = weights.sum(axis=1)
    off = np.abs(sums - 1.0) > WEIGHT_SUM_TOLERANCE
    if off.any():
        worst = float(sums[np.argmax(np.abs(sums - 1.0))])
        _invalid(f"{int(off.sum())} of {len(sums)} vertices have skin weights that do not sum to "
                 f"1 (within {WEIGHT_SUM_TOLERANCE}; the worst sums to {worst:.4g}): normalise "
                 "the weights before exporting")
    return weights / sums[:, None]


# ------------------------------------------------------------------------------------- names

def _smpl_style(name: str) -> int | None:
    """An SMPL-FBX-style joint name ("m_avg_L_Hip", "Pelvis", "rig:smpl_R_Knee") -> SMPL index."""
    s = name.rsplit(":", 1)[-1].strip().lower()
    for prefix in SMPL_PREFIXES:
        if s.startswith(prefix):
            s = s[len(prefix):]
            break
    if s.startswith("l_"):
        s = "left_" + s[2:]
    elif s.startswith("r_"):
        s = "right_" + s[2:]
    return JOINT_INDEX.get(s)


def _smpl_indices(names: list[str | None], joint_map: dict[str, str] | None) -> list[int]:
    """Each skin joint's SMPL index (-1: none); every SMPL joint must be matched exactly once."""
    smpl = [-1] * len(names)
    if joint_map:
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in joint_map.items()):
            _invalid("must map joint names (strings) to SMPL joint names (strings)", "joint_map")
        known = set(names)  # a set: a map of K keys against J joints is K lookups, not K x J comparisons
        unknown_keys = sorted(k for k in joint_map if k not in known)
        if unknown_keys:
            _invalid(f"names joints the skin does not have: {quoted(unknown_keys)}; "
                     f"the skin's joints: {quoted([n for n in names if n is not None])}", "joint_map")
        unknown_values = sorted({v for v in joint_map.values() if v not in JOINT_INDEX})
        if unknown_values:
            _invalid(f"maps to names that are not SMPL joints: "
                     f"{quoted(unknown_values)}; the SMPL joints are {', '.join(JOINT_NAMES)}", "joint_map")
        for k, name in enumerate(names):
            if name is not None and name in joint_map:
                smpl[k] = JOINT_INDEX[joint_map[name]]
    else:
        for k, name in enumerate(names):
            if name is not None:
                found = JOINT_INDEX.get(name)
                found = _smpl_style(name) if found is None else found
                smpl[k] = -1 if found is None else found
    claimed: dict[int, list[str]] = {}
    for k, j in enumerate(smpl):
        if j >= 0:
            claimed.setdefault(j, []).append(str(names[k]))
    twice = {JOINT_NAMES[j]: ks for j, ks in claimed.items() if len(ks) > 1}
    if twice:
        smpl_name, ks = next(iter(sorted(twice.items())))
        _invalid(f"the SMPL joint {smpl_name} is matched by {len(ks)} joints of the file "
                 f"({quoted(ks)}); give joint_map naming one joint per SMPL joint")
    missing = [n for j, n in enumerate(JOINT_NAMES) if j not in claimed]
    if missing:
        unmatched = [str(n) for k, n in enumerate(names) if smpl[k] < 0]
        _invalid(f"no joint of the file matches the SMPL joints {', '.join(missing)}; give "
                 "joint_map (file joint name -> SMPL joint name) for them; the file's joints "
                 f"that match none: {quoted(unmatched)}")
    return smpl


def _weight_targets(smpl: list[int], joint_nodes: list[int], parents: list[int]) -> np.ndarray:
    """Each skin joint -> the SMPL joint its weight goes to: its own, else its nearest mapped
    ancestor node's, else -1."""
    mapped = {joint_nodes[k]: j for k, j in enumerate(smpl) if j >= 0}
    above: dict[int, int] = {}  # unmapped node -> its nearest mapped ancestor's SMPL joint (-1: none), once each
    target = np.array(smpl, dtype=np.int64)
    for k, j in enumerate(smpl):
        if j >= 0:
            continue
        # each node is walked once (a chain of J unmapped joints is J steps, not J^2 / 2)
        path: list[int] = []
        n = parents[joint_nodes[k]]
        while n >= 0 and n not in mapped and n not in above and len(path) <= len(parents):
            path.append(n)
            n = parents[n]
        found = mapped[n] if n in mapped else above.get(n, -1)
        above.update(dict.fromkeys(path, found))
        target[k] = found
    return target
