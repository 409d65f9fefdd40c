"""User bodies (POST /v1/bodies, GET and DELETE /v1/bodies/{name}): reading an upload, checking it against
the body contract, and the documents the routes answer with; nothing here knows HTTP.

The body contract (the presets' arrays, drape.assets.body): vertices (V, 3) m, faces (F, 3), weights (V, 24)
rows summing to 1, joints (24, 3) m, in SMPL's joint order and hierarchy, T-pose rest, +Y up, facing +Z.
An upload is a skinned GLB/glTF (its skin's joints named as SMPL's, or through a `joint_map`) or an npz of
those arrays (`parents` and `joint_names` optional; with `joint_names`, the joints may come in any order). A
body given in another rest pose is un-posed with its own skinning when `rest_pose` (24, 3) axis-angle
radians says which.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drape.assets.body import Body
from drape.geometry.lbs import SingularSkinning, unpose_body
from drape.geometry.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS, PARENTS
from drape.runtime.body_store import BodyStore, body_id
from drape.service.decode import json_reals, known_form_fields, npz_members, npz_numbers
from drape.service.errors import InvalidInput, quoted
from drape.service.handlers import check_mesh
from drape.service.http import DuplicateKey, loads, parse_form
from drape.service.settings import Settings

FILE_FIELD = "body_file"
FORM_FIELDS = (FILE_FIELD, "joint_map", "rest_pose")
NPZ_MEMBERS = ("vertices", "faces", "weights", "joints", "parents", "joint_names", "rest_pose")
WEIGHT_SUM_TOLERANCE = 1e-3
MIN_HEIGHT_M, MAX_HEIGHT_M = 0.5, 2.6
MAX_ARM_TILT_DEG = 30.0  # a T-pose's upper arms lie within this of horizontal
JOINT_SLACK_M = 0.1  # rest joints lie within the mesh's bounding box grown by this


def _numbers(value: Any, field: str, shape: tuple[int, ...], what: str) -> np.ndarray:
    if isinstance(value, np.ndarray) and value.dtype.kind not in "iuf":
        raise InvalidInput(f"expected real numbers, got dtype {value.dtype}", field)
    if not isinstance(value, np.ndarray) and not json_reals(value):
        raise InvalidInput("expected numbers in nested lists, got strings, booleans or nulls", field)
    try:
        a = np.asarray(value, dtype=np.float64)
    except (ValueError, TypeError, OverflowError) as exc:
        raise InvalidInput(f"not a rectangular numeric array ({exc})", field) from exc
    if a.shape != shape:
        if a.ndim == 2 and len(shape) == 2 and shape[1] == NUM_JOINTS and a.shape[1] != NUM_JOINTS:
            raise InvalidInput(f"a body needs {NUM_JOINTS} joints in SMPL order, got {a.shape[1]} columns", field)
        if a.ndim == 2 and shape == (NUM_JOINTS, 3) and a.shape[0] != NUM_JOINTS:
            raise InvalidInput(f"a body needs {NUM_JOINTS} joints in SMPL order, got {a.shape[0]}", field)
        raise InvalidInput(f"expected {what} {shape}, got {a.shape}", field)
    if not np.isfinite(a).all():
        raise InvalidInput("contains NaN or infinite values", field)
    return a


def _joint_order(names: Any) -> np.ndarray:
    """joint_names (24,) in any order -> the index of each SMPL joint among them."""
    if not isinstance(names, np.ndarray) or names.dtype.kind != "U" or names.shape != (NUM_JOINTS,):
        shape, dtype = getattr(names, "shape", None), getattr(names, "dtype", None)
        if shape == (NUM_JOINTS,):  # the count is right: the type is not (bytes, numbers)
            raise InvalidInput(f"expected {NUM_JOINTS} joint names as unicode text (numpy dtype <U), got dtype "
                               f"{dtype}", "joint_names")
        raise InvalidInput(f"expected {NUM_JOINTS} joint names (text), got shape {shape}", "joint_names")
    given = [str(n) for n in names]
    unknown = [n for n in given if n not in JOINT_INDEX]
    if unknown:
        raise InvalidInput(f"{quoted(unknown[0], 40)} is not a SMPL joint name; expected {', '.join(JOINT_NAMES)}",
                           "joint_names")
    if len(set(given)) < NUM_JOINTS:
        raise InvalidInput("a joint name repeats", "joint_names")
    return np.array([given.index(n) for n in JOINT_NAMES])


def _check_parents(parents: Any) -> None:
    p = np.asarray(parents)
    if p.dtype.kind not in "iu" or p.shape != (NUM_JOINTS,):
        raise InvalidInput(f"expected {NUM_JOINTS} integer parent indices, got dtype {p.dtype} shape {p.shape}",
                           "parents")
    if p[0] != -1:
        raise InvalidInput(f"the root (joint 0) must have parent -1, got {p[0]}", "parents")
    for k in range(1, NUM_JOINTS):
        if not 0 <= p[k] < k:
            raise InvalidInput(f"not a tree in SMPL order: joint {k}'s parent {p[k]} is not an earlier joint",
                               "parents")
    differ = [JOINT_NAMES[k] for k in range(NUM_JOINTS) if p[k] != PARENTS[k]]
    if differ:
        raise InvalidInput(f"the hierarchy differs from SMPL's at {', '.join(differ)}: motions are SMPL poses",
                           "parents")


def _check_shape(vertices: np.ndarray, joints: np.ndarray, field: str) -> None:
    """Metres, +Y up, facing +Z, T-pose: refuse what is clearly otherwise, saying what it looks like."""
    height = float(vertices[:, 1].max() - vertices[:, 1].min())
    extent = float(np.ptp(vertices, axis=0).max())
    if extent > MAX_HEIGHT_M:
        looks = "centimetres" if extent < 300 else "millimetres"
        raise InvalidInput(f"the body is {extent:.4g} units across: it must be in metres (it looks like {looks})",
                           f"{field}vertices")
    spine = joints[JOINT_INDEX["head"]] - joints[JOINT_INDEX["pelvis"]]
    if spine[1] < 0.7 * np.linalg.norm(spine):
        axis = "XYZ"[int(np.argmax(np.abs(spine)))]
        sign = "+" if spine[int(np.argmax(np.abs(spine)))] > 0 else "-"
        raise InvalidInput(f"the head is not above the pelvis along +Y (it is along {sign}{axis}): the body must be "
                           "+Y up", f"{field}joints")
    if height < MIN_HEIGHT_M:
        raise InvalidInput(f"the body is {height:.3g} m tall, below {MIN_HEIGHT_M} m: it must be in metres",
                           f"{field}vertices")
    if joints[JOINT_INDEX["left_hip"], 0] <= joints[JOINT_INDEX["right_hip"], 0]:
        raise InvalidInput("the left hip is not on +X of the right hip: the body must face +Z", f"{field}joints")
    lo, hi = vertices.min(axis=0) - JOINT_SLACK_M, vertices.max(axis=0) + JOINT_SLACK_M
    outside = np.flatnonzero(((joints < lo) | (joints > hi)).any(axis=1))
    if len(outside):
        raise InvalidInput(f"the joint {JOINT_NAMES[outside[0]]} lies outside the mesh: joints and vertices must "
                           "be in one space, metres", f"{field}joints")
    for side in ("left", "right"):
        arm = joints[JOINT_INDEX[f"{side}_wrist"]] - joints[JOINT_INDEX[f"{side}_shoulder"]]
        tilt = float(np.degrees(np.arcsin(min(1.0, abs(arm[1]) / max(np.linalg.norm(arm), 1e-9)))))
        if tilt > MAX_ARM_TILT_DEG:
            raise InvalidInput(f"the rest pose is not a T-pose: the {side} arm is {tilt:.0f} degrees from horizontal;"
                               " give rest_pose, (24, 3) axis-angle radians of the pose the body is in",
                               f"{field}joints")


MIN_SURFACE_SHARE = 0.95  # of a body's vertices on its faces (the embedded bodies: all of them)


def check_body_arrays(arrays: dict[str, Any], settings: Settings, *, field: str = "",
                      rest_pose: Any = None) -> Body:
    """The body contract's arrays (vertices, faces, weights, joints; optional parents, joint_names) -> a Body
    named by its content (`body_id`), or InvalidInput / LimitExceeded naming the field (`field` prefixes
    the names). rest_pose (24, 3) radians: the pose the body is given in, un-posed to the T-pose."""
    pre = f"{field}." if field else ""
    v, f = check_mesh(arrays.get("vertices"), arrays.get("faces"), settings, field=field, max_abs=1e5)
    on_faces = len(np.unique(f)) / len(v)
    if on_faces < MIN_SURFACE_SHARE:
        raise InvalidInput(f"only {on_faces:.1%} of the {len(v)} vertices lie on a face: a body is its surface (the "
                           f"garment is kept out of it), so at least {MIN_SURFACE_SHARE:.0%} of them must",
                           f"{pre}faces")
    w = _numbers(arrays.get("weights"), f"{pre}weights", (len(v), NUM_JOINTS), "(V, 24) weights,")
    j = _numbers(arrays.get("joints"), f"{pre}joints", (NUM_JOINTS, 3), "rest joint positions")
    if arrays.get("joint_names") is not None:
        order = _joint_order(arrays["joint_names"])
        w, j = w[:, order], j[order]
    if arrays.get("parents") is not None:
        _check_parents(arrays["parents"])
    if w.min() < -1e-6:
        raise InvalidInput(f"weights must be non-negative, got {w.min():.3g}", f"{pre}weights")
    sums = w.sum(axis=1)
    off = np.abs(sums - 1.0) > WEIGHT_SUM_TOLERANCE
    if off.any():
        worst = sums[np.argmax(np.abs(sums - 1.0))]
        raise InvalidInput(f"{int(off.sum())} of {len(w)} vertices' weights do not sum to 1 (worst: {worst:.4g})",
                           f"{pre}weights")
    w = np.clip(w, 0.0, None)
    if np.abs(w.sum(axis=1) - 1.0).max() > 1e-6:  # only when needed: a stored body re-checked keeps its bytes
        w /= w.sum(axis=1, keepdims=True)
    vertices, joints = v.astype(np.float64), j
    if rest_pose is not None:
        pose = _numbers(rest_pose, "rest_pose", (NUM_JOINTS, 3), "axis-angle radians")
        if np.abs(pose).max() > 2 * np.pi:
            raise InvalidInput("angles must lie within 2 pi radians", "rest_pose")
        try:
            vertices, joints = unpose_body(vertices, w, joints, pose)
        except SingularSkinning as exc:
            raise InvalidInput(str(exc), "rest_pose") from None
    _check_shape(vertices, joints, pre)
    arrays_out = {"vertices": vertices.astype(np.float32), "faces": f.astype(np.int32),
                  "weights": w.astype(np.float32), "joints": joints.astype(np.float32)}
    for a in arrays_out.values():
        a.setflags(write=False)
    return Body(name=body_id(**arrays_out), parents=PARENTS, joint_names=JOINT_NAMES, **arrays_out)


def _form_json(parts: dict[str, Any], name: str) -> Any:
    part = parts.get(name)
    if part is None:
        return None
    try:
        return loads(part.data)
    except DuplicateKey as exc:
        raise InvalidInput(str(exc), name) from None
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise InvalidInput(f"expected JSON text ({type(exc).__name__})", name) from None


def read_upload(kind: str, content_type: str, data: bytes, settings: Settings) -> Body:
    """A POST /v1/bodies body (kind: its media type) -> the checked Body (not yet stored)."""
    if kind == "multipart/form-data":
        parts = parse_form(data, content_type)
        known_form_fields(parts, FORM_FIELDS)
        if FILE_FIELD not in parts:
            raise InvalidInput("a body file is required: a skinned GLB / glTF, or an npz of the body's arrays",
                               FILE_FIELD)
        part = parts[FILE_FIELD]
        rest_pose = _form_json(parts, "rest_pose")
        joint_map = _form_json(parts, "joint_map")
        if joint_map is not None and not (isinstance(joint_map, dict)
                                          and all(isinstance(k, str) and isinstance(x, str)
                                                  for k, x in joint_map.items())):
            raise InvalidInput("expected a JSON object from the file's joint names to SMPL's", "joint_map")
        return read_body_file(part.data, part.filename or "", settings, joint_map=joint_map, rest_pose=rest_pose)
    return _npz_body(data, settings, "", None)


def read_body_file(data: bytes, filename: str, settings: Settings, *, joint_map: dict[str, str] | None = None,
                   rest_pose: Any = None, field: str = FILE_FIELD) -> Body:
    """A body file's bytes (a skinned GLB / glTF, or an npz of the body's arrays; told apart by their first bytes,
    else by the file name) -> the checked Body (not yet stored); what POST /v1/bodies' `body_file` and the
    command line's `--body FILE` read. Errors name `field`."""
    from drape.service.body_files import body_from_glb

    name = filename.lower()
    if data[:4] == b"glTF" or name.endswith((".glb", ".gltf")):
        arrays = body_from_glb(data, joint_map=joint_map, max_vertices=settings.max_vertices,
                               max_faces=settings.max_faces)
        return check_body_arrays(arrays, settings, field=field, rest_pose=rest_pose)
    if data[:2] == b"PK" or name.endswith(".npz"):
        if joint_map is not None:
            raise InvalidInput("joint_map applies to GLB / glTF files; an npz names its joints in joint_names",
                               "joint_map")
        return _npz_body(data, settings, field, rest_pose)
    raise InvalidInput("expected a GLB / glTF file or an npz archive", field)


def _npz_body(data: bytes, settings: Settings, field: str, rest_pose: Any) -> Body:
    z = npz_members(data, NPZ_MEMBERS, settings, field or "body")
    missing = [k for k in ("vertices", "faces", "weights", "joints") if k not in z]
    if missing:
        raise InvalidInput(f"the archive lacks {', '.join(missing)}", field or "body")
    arrays: dict[str, Any] = {"vertices": npz_numbers(z, "vertices"), "faces": npz_numbers(z, "faces", integer=True),
                              "weights": npz_numbers(z, "weights"), "joints": npz_numbers(z, "joints"),
                              "parents": z.get("parents"), "joint_names": z.get("joint_names")}
    if rest_pose is not None and "rest_pose" in z:  # one was read without a word, the other dropped
        raise InvalidInput(f"given twice: as a form field and as the {field or 'body'} archive's rest_pose member; "
                           "give one", "rest_pose")
    if "rest_pose" in z:
        rest_pose = npz_numbers(z, "rest_pose")
    return check_body_arrays(arrays, settings, field=field, rest_pose=rest_pose)


def stored_body(arrays: dict[str, np.ndarray], name: str, settings: Settings) -> Body:
    """A body file read back from DRAPE_BODY_DIR, checked again; its name must still be its content's."""
    body = check_body_arrays(arrays, settings)
    if body.name != name:
        raise ValueError(f"the file's arrays hash to {body.name}, not {name}")
    return body


def register(store: BodyStore, body: Body) -> int:
    """Hold the body, one registration more -> its registrations (1: new). A full store is a domain error (the
    store's message)."""
    from drape.runtime.body_store import StoreFull
    from drape.service.errors import StoreIsFull

    try:
        return store.add(body)
    except StoreFull as exc:
        raise StoreIsFull(str(exc), "body") from None


def body_arrays(body: Body) -> dict[str, np.ndarray]:
    """A body's arrays as GET /v1/bodies/{name} answers them."""
    return {"vertices": body.vertices, "faces": body.faces, "weights": body.weights, "joints": body.joints,
            "parents": body.parents, "joint_names": np.array(body.joint_names, dtype=np.str_)}


def summary(body: Body) -> dict[str, Any]:
    return {"body_id": body.name, "num_vertices": int(len(body.vertices)), "num_faces": int(len(body.faces)),
            "height": float(np.ptp(body.vertices[:, 1]))}
