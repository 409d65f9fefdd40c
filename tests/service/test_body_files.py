"""body_from_glb against files written by drape's own GLB writer (edited with pygltflib): the neutral
body round-trips; SMPL-FBX names and joint maps are matched; unmapped joints give their weight to a
mapped ancestor; a posed armature gives the shape it shows; bad files are refused with the right
class and a detail naming what to fix."""

from __future__ import annotations

import base64
from collections.abc import Callable

import numpy as np
import pygltflib as gl
import pytest

from drape.assets.body import load_body
from drape.geometry.lbs import pose_mesh
from drape.geometry.rotations import axis_angle_to_quaternion
from drape.geometry.skeleton import forward_kinematics
from drape.schemas.gltf import Skeleton, SkinnedMesh, skin_sets, skinned_glb
from drape.service.body_files import _smpl_indices, _weight_targets, body_from_glb
from drape.service.errors import DrapeError, InvalidInput, LimitExceeded, MalformedInput

BODY = load_body("neutral")
V, F = len(BODY.vertices), len(BODY.faces)
FBX = {"pelvis": "m_avg_Pelvis", "spine1": "m_avg_Spine1", "spine2": "m_avg_Spine2",
       "spine3": "m_avg_Spine3", "neck": "m_avg_Neck", "head": "m_avg_Head"}


def _fbx_name(name: str) -> str:
    """left_hip -> m_avg_L_Hip (the SMPL FBX export's names)."""
    if name in FBX:
        return FBX[name]
    side, part = name.split("_", 1)
    return f"m_avg_{side[0].upper()}_{part.capitalize()}"


def _write(names=BODY.joint_names, parents=BODY.parents, joints=BODY.joints,
           weights=BODY.weights) -> bytes:
    skeleton = Skeleton(tuple(names), np.asarray(parents), np.asarray(joints))
    return skinned_glb(skeleton, [SkinnedMesh("body", BODY.vertices, BODY.faces, weights)])


@pytest.fixture(scope="module")
def glb() -> bytes:
    return _write()


def _stored(weights: np.ndarray) -> np.ndarray:
    """The dense (V, K) weights the writer stores (skin_sets: influences >= 1e-5, renormalised)."""
    joints, ws = skin_sets(weights)
    dense = np.zeros(np.shape(weights))
    np.add.at(dense, (np.arange(len(ws))[:, None].repeat(ws.shape[1], 1), joints), ws)
    return dense / dense.sum(axis=1, keepdims=True)


def _read(data: bytes, joint_map: dict[str, str] | None = None, max_vertices: int = 100_000,
          max_faces: int = 100_000) -> dict[str, np.ndarray]:
    return body_from_glb(data, joint_map=joint_map, max_vertices=max_vertices, max_faces=max_faces)


def _edit(data: bytes, change: Callable[[gl.GLTF2, bytearray], None]) -> bytes:
    doc = gl.GLTF2.load_from_bytes(data)
    blob = bytearray(doc.binary_blob())
    change(doc, blob)
    blob += bytes(-len(blob) % 4)
    doc.buffers[0].byteLength = len(blob)
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())


def _overwrite(doc: gl.GLTF2, blob: bytearray, accessor: int, array: np.ndarray) -> None:
    view = doc.bufferViews[doc.accessors[accessor].bufferView]
    data = np.ascontiguousarray(array).tobytes()
    assert len(data) == view.byteLength
    blob[view.byteOffset:view.byteOffset + len(data)] = data


def _append(doc: gl.GLTF2, blob: bytearray, array: np.ndarray, kind: str, component: int,
            normalized: bool = False) -> int:
    blob += bytes(-len(blob) % 4)
    data = np.ascontiguousarray(array).tobytes()
    doc.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data)))
    blob += data
    doc.accessors.append(gl.Accessor(bufferView=len(doc.bufferViews) - 1, componentType=component,
                                     count=len(array), type=kind, normalized=normalized or None))
    return len(doc.accessors) - 1


def _attributes(doc: gl.GLTF2) -> gl.Attributes:
    return doc.meshes[0].primitives[0].attributes


def _refused(cls: type[DrapeError], data: bytes, *fragments: str, field: str = "body_file", **kwargs) -> str:
    with pytest.raises(DrapeError) as info:
        _read(data, **kwargs)
    assert type(info.value) is cls, info.value.detail
    assert info.value.field == field
    assert info.value.detail.startswith(f"{field}: ")
    for fragment in fragments:
        assert fragment in info.value.detail, info.value.detail
    assert len(info.value.detail) < 800
    return info.value.detail


# ------------------------------------------------------------------------------------ reading

def test_the_neutral_body_round_trips_through_a_glb(glb):
    out = _read(glb)
    assert out["vertices"].shape == (V, 3) and out["vertices"].dtype == np.float64
    assert out["faces"].dtype == np.int64 and out["weights"].dtype == np.float64
    assert out["joints"].shape == (24, 3) and out["weights"].shape == (V, 24)
    assert np.abs(out["vertices"] - BODY.vertices).max() < 1e-5
    assert np.array_equal(out["faces"], BODY.faces)
    assert np.abs(out["joints"] - BODY.joints).max() < 1e-5
    stored = _stored(BODY.weights)
    assert (stored > 0).sum(axis=1).max() > 4  # the writer needed JOINTS_1 / WEIGHTS_1
    assert np.abs(out["weights"] - stored).max() < 1e-6
    assert np.abs(out["weights"].sum(axis=1) - 1).max() < 1e-12


def test_a_gltf_with_embedded_buffers_reads_as_its_glb(glb):
    doc = gl.GLTF2.load_from_bytes(glb)
    blob = doc.binary_blob()
    doc.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    doc.destroy_binary_blob()
    out = _read(doc.to_json().encode())
    want = _read(glb)
    for key in want:
        assert np.array_equal(out[key], want[key]), key


def test_smpl_fbx_style_names_are_matched():
    names = [_fbx_name(n) for n in BODY.joint_names]
    assert names[:3] == ["m_avg_Pelvis", "m_avg_L_Hip", "m_avg_R_Hip"]
    names[4] = "rig:f_avg_l_knee"  # a "prefix:" and another SMPL prefix, lower case
    names[7] = "smpl_L_ANKLE"
    names[0] = "Pelvis"
    out = _read(_write(names=names))
    assert np.abs(out["joints"] - BODY.joints).max() < 1e-5
    assert np.abs(out["weights"] - _stored(BODY.weights)).max() < 1e-6


def test_a_joint_map_names_arbitrary_joints():
    order = np.random.default_rng(0).permutation(24)  # bone_k is SMPL joint order[k]
    names = [""] * 24
    for k, j in enumerate(order):
        names[j] = f"bone_{k}"
    joint_map = {f"bone_{k}": BODY.joint_names[j] for k, j in enumerate(order)}
    data = _write(names=names)
    _refused(InvalidInput, data, "no joint of the file matches the SMPL joints pelvis, left_hip",
             "joint_map")  # without the map
    out = _read(data, joint_map=joint_map)
    assert np.abs(out["joints"] - BODY.joints).max() < 1e-5
    assert np.abs(out["weights"] - _stored(BODY.weights)).max() < 1e-6
    # a wrong map: joints swapped -> the columns follow the map
    swapped = dict(joint_map, **{names[16]: "right_shoulder", names[17]: "left_shoulder"})
    out = _read(data, joint_map=swapped)
    assert np.allclose(out["joints"][16], BODY.joints[17], atol=1e-5)
    assert np.abs(out["weights"][:, 16] - _stored(BODY.weights)[:, 17]).max() < 1e-6


def test_the_body_is_the_skinned_node_named_body_when_a_garment_is_skinned_before_it():
    """drape's rig GLB holds the outfit skinned to the skeleton, then the body: registering it read the outfit
    ("the joint left_knee lies outside the mesh"); the node named body is the body."""
    skeleton = Skeleton(tuple(BODY.joint_names), np.asarray(BODY.parents), np.asarray(BODY.joints))
    shirt = np.flatnonzero(BODY.vertices[:, 1] > np.median(BODY.vertices[:, 1]))[:300]
    faces = np.array([[0, 1, 2], [2, 1, 3]])
    outfit = SkinnedMesh("outfit", BODY.vertices[shirt] * 1.05, faces, BODY.weights[shirt])
    out = _read(skinned_glb(skeleton, [outfit, SkinnedMesh("Body", BODY.vertices, BODY.faces, BODY.weights)]))
    np.testing.assert_allclose(out["vertices"], BODY.vertices, atol=1e-6)
    assert len(out["faces"]) == len(BODY.faces)
    only = _read(skinned_glb(skeleton, [SkinnedMesh("mesh", BODY.vertices, BODY.faces, BODY.weights), outfit]))
    assert len(only["vertices"]) == len(BODY.vertices)  # no node named body: the first skinned one, as before


def test_joint_map_mistakes_are_refused(glb):
    identity = {n: n for n in BODY.joint_names}
    # a map that names what is not there is the joint_map field's mistake, not the file's
    _refused(InvalidInput, glb, "joint_map: names joints the skin does not have", "'Hips'", field="joint_map",
             joint_map=dict(identity, Hips="pelvis"))
    _refused(InvalidInput, glb, "joint_map: maps to names that are not SMPL joints", "'lefthip'", field="joint_map",
             joint_map=dict(identity, left_hip="lefthip"))
    _refused(InvalidInput, glb, "must map joint names (strings)", field="joint_map", joint_map=dict(identity, pelvis=3))
    _refused(InvalidInput, glb, "SMPL joint left_hip is matched by 2 joints", "joint_map",
             joint_map=dict(identity, right_hip="left_hip"))


def test_an_unmapped_jaw_gives_its_weight_to_head():
    names = BODY.joint_names + ("jaw",)
    parents = np.append(BODY.parents, 15)
    joints = np.vstack([BODY.joints, BODY.joints[15] + [0.0, 0.03, 0.06]])
    weights = np.hstack([BODY.weights, np.zeros((V, 1), np.float32)])
    face = weights[:, 15] > 0.5
    weights[face, 24] = 0.4 * weights[face, 15]
    weights[face, 15] *= 0.6
    assert face.sum() > 100
    out = _read(_write(names, parents, joints, weights))
    stored = _stored(weights)
    assert stored[:, 24].max() > 0.3  # the file does weight the jaw
    merged = stored[:, :24].copy()
    merged[:, 15] += stored[:, 24]
    assert np.abs(out["weights"] - merged).max() < 1e-6
    assert np.abs(out["vertices"] - BODY.vertices).max() < 1e-5
    assert np.abs(out["joints"] - BODY.joints).max() < 1e-5


def test_an_unmapped_root_is_fine_until_it_carries_weight():
    names = ("root",) + BODY.joint_names
    parents = np.concatenate([[-1], np.where(BODY.parents >= 0, BODY.parents + 1, 0)])
    joints = np.vstack([[0.0, 0.0, 0.0], BODY.joints])
    weights = np.hstack([np.zeros((V, 1), np.float32), BODY.weights])
    out = _read(_write(names, parents, joints, weights))
    assert np.abs(out["weights"] - _stored(BODY.weights)).max() < 1e-6
    weights[:50] = 0
    weights[:50, 0] = 1  # 50 vertices weighted to the root alone
    _refused(InvalidInput, _write(names, parents, joints, weights), "50 vertices",
             "no mapped ancestor", "'root'")


class _Reads(list):
    """A parents list that counts its reads."""

    reads = 0

    def __getitem__(self, i):  # type: ignore[override]
        _Reads.reads += 1
        return super().__getitem__(i)


class _Name(str):
    """A joint name that counts its comparisons."""

    compared = 0
    __hash__ = str.__hash__

    def __eq__(self, other: object) -> bool:
        _Name.compared += 1
        return str.__eq__(self, other)


def test_a_long_chain_of_unmapped_joints_and_a_long_joint_map_take_linear_steps():
    """Under the hand, a chain of J joints that map to no SMPL joint each give their weight to the hand, in J
    parent reads (each walked to its nearest mapped ancestor once): it took J^2 / 2 (a skin of ~25,000 joints,
    within the glTF token limit, held a computing slot for minutes); and a joint_map of K keys is checked against
    the skin's J names by lookups, not K x J comparisons (a joint_map form field is bounded only by the body)."""
    J = 3000
    parents = _Reads([*BODY.parents.tolist(), *range(23, 23 + J)])
    smpl = [*range(24), *[-1] * J]
    _Reads.reads = 0
    target = _weight_targets(smpl, list(range(24 + J)), parents)
    assert target[24:].tolist() == [23] * J and target[:24].tolist() == list(range(24))
    assert _Reads.reads < 4 * (24 + J), _Reads.reads

    names = [_Name(n) for n in (*BODY.joint_names, *(f"bone_{k}" for k in range(J)))]
    joint_map = {**{n: n for n in BODY.joint_names}, **{f"x{k}": "head" for k in range(2000)}}
    _Name.compared = 0
    with pytest.raises(InvalidInput, match="names joints the skin does not have: \\['x0'"):
        _smpl_indices(names, joint_map)
    assert _Name.compared < 1000, _Name.compared
    assert _smpl_indices(names, {n: n for n in BODY.joint_names}) == [*range(24), *[-1] * J]


def _pose_nodes(poses: np.ndarray) -> Callable[[gl.GLTF2, bytearray], None]:
    def change(doc: gl.GLTF2, blob: bytearray) -> None:
        q = axis_angle_to_quaternion(poses)  # w, x, y, z
        for k in range(24):
            if np.any(poses[k]):
                doc.nodes[k].rotation = [float(c) for c in (*q[k, 1:], q[k, 0])]
    return change


def test_an_armature_away_from_bind_pose_gives_the_shape_it_shows(glb):
    poses = np.zeros((24, 3))
    poses[16] = [0.0, 0.0, -1.1]  # left shoulder: the arm down
    poses[9] = [0.3, 0.2, 0.0]  # spine3: the chest leans
    poses[4] = [0.8, 0.0, 0.0]  # left knee
    out = _read(_edit(glb, _pose_nodes(poses)))
    stored = _stored(BODY.weights)
    want = pose_mesh(BODY.vertices, stored, BODY.joints, poses[None], None, BODY.parents)[0]
    assert np.abs(want - BODY.vertices).max() > 0.3  # the pose moves the body a lot
    assert np.abs(out["vertices"] - want).max() < 1e-5
    _, posed_joints = forward_kinematics(poses[None], BODY.joints, BODY.parents)
    assert np.abs(out["joints"] - posed_joints[0]).max() < 1e-5
    assert np.abs(out["weights"] - stored).max() < 1e-6
    assert np.array_equal(out["faces"], BODY.faces)


def test_a_node_above_the_armature_moves_body_and_joints(glb):
    def parent_node(doc: gl.GLTF2, blob: bytearray) -> None:
        # a column-major matrix: scale 2 and a translation, as an "Armature" node above the pelvis
        m = np.diag([2.0, 2.0, 2.0, 1.0])
        m[:3, 3] = [0.5, 0.0, -1.0]
        doc.nodes.append(gl.Node(name="Armature", children=[0], matrix=m.T.reshape(-1).tolist()))
        doc.scenes[0].nodes[0] = len(doc.nodes) - 1

    out = _read(_edit(glb, parent_node))
    assert np.abs(out["vertices"] - (2 * BODY.vertices + [0.5, 0.0, -1.0])).max() < 1e-5
    assert np.abs(out["joints"] - (2 * BODY.joints + [0.5, 0.0, -1.0])).max() < 1e-5


def test_normalised_unsigned_byte_weights(glb):
    joints, ws = skin_sets(BODY.weights)
    q = np.round(ws.astype(np.float64) * 255)
    q[:, 0] += 255 - q.sum(axis=1)  # the largest weight takes the rounding: rows sum to 255
    assert q.min() >= 0

    def to_bytes(doc: gl.GLTF2, blob: bytearray) -> None:
        attributes = _attributes(doc)
        attributes.WEIGHTS_0 = _append(doc, blob, q[:, :4].astype(np.uint8), gl.VEC4,
                                       gl.UNSIGNED_BYTE, normalized=True)
        attributes.WEIGHTS_1 = _append(doc, blob, q[:, 4:].astype(np.uint8), gl.VEC4,
                                       gl.UNSIGNED_BYTE, normalized=True)

    out = _read(_edit(glb, to_bytes))
    want = np.zeros((V, 24))
    np.add.at(want, (np.arange(V)[:, None].repeat(8, 1), joints), q / 255)
    assert np.abs(out["weights"] - want).max() < 1e-12
    assert np.abs(out["weights"] - _stored(BODY.weights)).max() < 4 / 255  # the rounding


# ------------------------------------------------------------------------------------- errors

def test_missing_smpl_joints_are_listed(glb):
    def rename(doc: gl.GLTF2, blob: bytearray) -> None:
        doc.nodes[22].name, doc.nodes[23].name = "LeftHandThing", "RightHandThing"

    _refused(InvalidInput, _edit(glb, rename),
             "no joint of the file matches the SMPL joints left_hand, right_hand; give joint_map",
             "the file's joints that match none: ['LeftHandThing', 'RightHandThing']")


def test_a_file_without_a_skinned_mesh_is_refused(glb):
    def unskin(doc: gl.GLTF2, blob: bytearray) -> None:
        doc.nodes[24].skin = None

    _refused(InvalidInput, _edit(glb, unskin), "the file has no skinned mesh: ")


def test_weights_not_summing_to_one_are_refused(glb):
    def halve(doc: gl.GLTF2, blob: bytearray) -> None:
        a = _attributes(doc).WEIGHTS_0
        view = doc.bufferViews[doc.accessors[a].bufferView]
        w = np.frombuffer(bytes(blob[view.byteOffset:view.byteOffset + view.byteLength]),
                          np.float32).reshape(-1, 4).copy()
        w[:7] *= 0.5
        w[7] *= 1.5
        _overwrite(doc, blob, a, w)

    _refused(InvalidInput, _edit(glb, halve), "8 of 13718 vertices", "do not sum to 1",
             "the worst sums to")


def test_a_nan_position_is_refused(glb):
    def nan(doc: gl.GLTF2, blob: bytearray) -> None:
        v = BODY.vertices.astype(np.float32)
        v[10, 1] = np.nan
        v[20, 0] = np.inf
        _overwrite(doc, blob, _attributes(doc).POSITION, v)

    _refused(InvalidInput, _edit(glb, nan), "2 vertex positions are not finite")


def test_too_many_vertices_or_faces_are_refused(glb):
    _refused(LimitExceeded, glb, f"{V} vertices", f"limit of {V - 1}", max_vertices=V - 1)
    _refused(LimitExceeded, glb, f"{F} triangles", f"limit of {F - 1}", max_faces=F - 1)
    assert len(_read(glb, max_vertices=V, max_faces=F)["vertices"]) == V


def test_a_file_that_is_not_a_glb_is_refused(glb):
    _refused(MalformedInput, b"solid cube\nfacet normal 0 0 1\n", "not a GLB")
    _refused(MalformedInput, glb[: len(glb) // 2], "the GLB header declares")
    _refused(MalformedInput, b'{"asset": {"version": "2.0"}, "nodes": [', "unreadable")


def test_a_node_transform_past_the_float_range_is_refused(glb):
    """JSON allows integers of any size: 10**400 in a joint's translation is refused, not a 500."""
    def huge(doc: gl.GLTF2, blob: bytearray) -> None:
        joint = doc.skins[0].joints[0]
        doc.nodes[joint].translation = [10 ** 400, 0, 0]

    _refused(InvalidInput, _edit(glb, huge), f"nodes[{gl.GLTF2.load_from_bytes(glb).skins[0].joints[0]}].translation",
             "not finite")
