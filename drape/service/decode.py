"""Request bodies -> the handlers' arguments: JSON (strict pydantic models), npz (only the members a
route uses, sizes checked from their headers before reading), multipart mesh uploads (checked by
`uploads`). Cheap checks come first: sizes and unknown ids are looked at on the parsed document before
the models validate every number. Pure CPU work, no HTTP: the routers call these off the event loop.
"""

from __future__ import annotations

import io
import re
from typing import Any

import numpy as np
from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails

from drape.geometry.mesh_io import obj_parts
from drape.runtime.engine import Engine
from drape.schemas.binary import NpzTooLarge, decode_npz
from drape.schemas.garments import (
    EncodeFields,
    EncodeRequest,
    KeyframeAnimateRequest,
    KeyframeFields,
    SampleFields,
    SampleRequest,
)
from drape.schemas.outfits import (
    AnimateRequest,
    FitRequest,
    RefineOptions,
    RefineRequest,
    RigRequest,
)
from drape.service import uploads
from drape.service.errors import InvalidInput, LimitExceeded, MalformedInput, field_name, quoted
from drape.service.garments import NPZ_MEMBERS_KEY
from drape.service.handlers import unknown_outfit
from drape.service.http import loads, parse_form, parse_json
from drape.service.settings import Settings

REFINE_OPTIONS = tuple(RefineOptions.model_fields)


def _request_path(error: ErrorDetails, doc: Any) -> tuple[tuple, tuple | None]:
    """An error's loc as a path into the request `doc` -> (the path, the union member it came from: the loc up to
    and including its first tag, None without one).

    pydantic puts the member of a union in the loc (`refine.bool`, `refine.RefineOptions.eps` for `bool |
    RefineOptions`); the client wrote `refine.eps`. A loc element the document does not hold at that point is such
    a tag and is dropped, but for the last of a `missing` error (the field that should be there)."""
    loc, path, node, member = error["loc"], [], doc, None
    for i, step in enumerate(loc):
        if isinstance(node, dict) and isinstance(step, str) and step in node:
            node = node[step]
        elif isinstance(node, list) and isinstance(step, int) and 0 <= step < len(node):
            node = node[step]
        elif not (i == len(loc) - 1 and error["type"] == "missing"):
            member = member or tuple(loc[:i + 1])
            continue
        path.append(step)
    return tuple(path), member


def _request_errors(exc: ValidationError, doc: Any = None) -> list[tuple[str, str]]:
    """(field, message) of each error, the field as the client wrote it. With `doc`, union member tags are
    dropped, and of a union's members only the errors of the one the input came closest to are kept: the member
    whose errors lie deepest, then the one with the fewest (ties: each) (`refine: {"eps": 0.5}` is `refine.eps: ... less than or
    equal to 0.05`, not also `refine: Input should be a valid boolean`; poses of (T, 24, 3) with one string name
    that string, not every value the (T, 72) member found to be a list)."""
    errors = exc.errors()
    if doc is None:
        return [(field_name(e["loc"]), e["msg"]) for e in errors]
    located = [(*_request_path(e, doc), e) for e in errors]
    members: dict[tuple, dict[tuple, list[int]]] = {}  # the union (loc before the tag) -> member -> loc lengths
    for _, member, e in located:
        if member is not None:
            members.setdefault(member[:-1], {}).setdefault(member, []).append(len(e["loc"]))

    def closeness(lengths: list[int]) -> tuple[int, int]:
        return max(lengths), -len(lengths)

    best = {}  # a tie keeps each (refine: "yes" is neither a bool nor options)
    for union, options in members.items():
        top = max(map(closeness, options.values()))
        best[union] = {m for m, lengths in options.items() if closeness(lengths) == top}
    return [(field_name(path), e["msg"]) for path, member, e in located
            if member is None or member in best[member[:-1]]]


def validation_error(exc: ValidationError, doc: Any = None) -> InvalidInput:
    """A request model's ValidationError as the 422: the detail names each wrong field (up to 5), and the
    problem's field member is the first (it was null while the detail named it). Given the request document
    `doc`, fields are named as the client wrote them (see _request_errors)."""
    errors = _request_errors(exc, doc)
    error = InvalidInput("; ".join(f"{field}: {msg}" for field, msg in errors[:5]))
    error.field = errors[0][0] or None if errors else None
    return error


def _model(model: type[BaseModel], doc: Any) -> Any:
    try:
        return model.model_validate(doc)
    except ValidationError as exc:
        raise validation_error(exc, doc) from exc


def _count(value: Any, limit: int, what: str, field: str) -> None:
    """A list's length against a limit, before its items are validated (a 413 naming the limit)."""
    if isinstance(value, list) and len(value) > limit:
        raise LimitExceeded(f"{len(value)} {what} exceed the limit of {limit}", field)


def _precheck_mesh(doc: Any, settings: Settings, field: str = "") -> None:
    if isinstance(doc, dict):
        pre = f"{field}." if field else ""
        _count(doc.get("vertices"), settings.max_vertices, "vertices", f"{pre}vertices")
        _count(doc.get("faces"), settings.max_faces, "faces", f"{pre}faces")


def _precheck_motion(doc: Any, settings: Settings) -> None:
    if isinstance(doc, dict):
        _count(doc.get("poses"), settings.max_frames, "frames", "motion.poses")


def json_reals(value: Any) -> bool:
    """Whether a parsed JSON value (a form field's) is numbers in nested lists: no strings, booleans or nulls,
    which numpy would read as numbers (strict, as the JSON models are). Walked without recursion."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, list):
            stack.extend(v)
        elif isinstance(v, bool) or not isinstance(v, int | float):
            return False
    return True


def _document(data: bytes, field: str = "body") -> dict:
    doc = parse_json(data, field)
    if not isinstance(doc, dict):
        raise InvalidInput(f"expected a JSON object, got {type(doc).__name__}", field)
    return doc


# ---- npz ----------------------------------------------------------------------------------------

NPZ_ALIASES = {"trans": "translation", "transl": "translation", "mocap_framerate": "fps", "mocap_frame_rate": "fps",
               "frame_rate": "fps"}  # other tools' names of a request's members


def npz_members(data: bytes, names: tuple[str, ...], settings: Settings,
                field: str = "body", strict: bool = False) -> dict[str, np.ndarray]:
    """The members `names` of an npz (others are never read), within DRAPE_MAX_DECODED_BYTES; errors name
    `field`: the request body, or the form field that carried the archive. strict (a request's own npz): a
    member that is not one of `names` is a 422 naming it, as an unknown JSON field is (it was dropped without a
    word: `trans` for `translation` animated the garment in place)."""
    try:
        z = decode_npz(data, names, max_bytes=settings.max_decoded_bytes)
    except NpzTooLarge as exc:
        raise LimitExceeded(str(exc), field) from exc
    except ValueError as exc:
        raise MalformedInput(str(exc), field) from exc
    if strict:
        import zipfile

        with zipfile.ZipFile(io.BytesIO(data)) as archive:  # read by decode_npz already: its names only
            for member in archive.namelist():
                key = member.removesuffix(".npy")
                if key not in names:
                    meant = NPZ_ALIASES.get(key)
                    hint = f" (did you mean {meant!r}?)" if meant in names else ""
                    raise InvalidInput(f"not a member this request reads{hint}; it reads {', '.join(names)}",
                                       key)
    return z


def npz_numbers(z: dict[str, np.ndarray], name: str, integer: bool = False) -> np.ndarray:
    """A real numeric member (integers only when `integer`): booleans, complex, strings are refused."""
    a = z[name]
    kinds = "iu" if integer else "iuf"
    if a.dtype.kind not in kinds:
        expected = "integers" if integer else "real numbers"
        raise InvalidInput(f"expected {expected}, got dtype {a.dtype}", name)
    return a


def npz_text(z: dict[str, np.ndarray], name: str) -> str | None:
    """A unicode scalar member (a name), or None when absent."""
    if name not in z:
        return None
    a = z[name]
    if a.dtype.kind != "U" or a.shape != ():
        raise InvalidInput(f"expected a text scalar, got dtype {a.dtype} and shape {a.shape}", name)
    return str(a)


def npz_scalar(z: dict[str, np.ndarray], name: str) -> float | int | None:
    """A real numeric scalar member, or None when absent."""
    if name not in z:
        return None
    a = z[name]
    if a.shape != () or a.dtype.kind not in "iuf":
        raise InvalidInput(f"expected a numeric scalar, got dtype {a.dtype} and shape {a.shape}", name)
    value = a.item()  # a Python number, but for longdouble, whose item() is numpy's own and failed float checks
    return float(value) if a.dtype.kind == "f" else int(value)


def npz_options(z: dict[str, np.ndarray]) -> dict | None:
    """The refine options among an npz's members (scalars eps, max_iterations, relief_iterations), validated
    like the JSON request's `options`; None when it has none."""
    return _refine_options({k: npz_scalar(z, k) for k in REFINE_OPTIONS if k in z})


def _refine_options(given: dict) -> dict | None:
    """Refine options given as loose values, validated like the JSON request's `options`; None for none."""
    if not given:
        return None
    try:
        return RefineOptions.model_validate(given).model_dump()
    except ValidationError as exc:
        raise validation_error(exc, given) from exc


# ---- the routes' bodies -------------------------------------------------------------------------

def refine_choice(flag: bool | None, options: dict | None) -> bool | dict:
    """refine given as a flag (None: not given) and/or the refine options (None: none; any of them turns refinement
    on) -> False, True or the options. The flag false beside options is a contradiction, not a choice to make for
    the client (the options were dropped): a 422 naming refine."""
    if flag is False and options:
        raise InvalidInput("false, but refine options (eps, max_iterations, relief_iterations) were given, which turn "
                           "refinement on: leave refine out or set it true, or drop the options", "refine")
    return options or bool(flag)


def npz_flag(z: dict[str, np.ndarray], name: str) -> bool | None:
    """A boolean scalar member, or None when absent."""
    if name not in z:
        return None
    flag = z[name]
    if flag.shape != () or flag.dtype.kind != "b":
        raise InvalidInput(f"expected a boolean scalar, got dtype {flag.dtype} and shape {flag.shape}", name)
    return bool(flag)


def _form_flag(parts: dict[str, Any], name: str) -> bool | None:
    text = _text(parts, name)
    if text not in (None, "true", "false", "1", "0"):
        raise InvalidInput(f"expected true or false, got {quoted(text, 40)}", name)
    return None if text is None else text in ("true", "1")


def _form_mesh(parts: dict[str, Any], settings: Settings) -> tuple[np.ndarray, np.ndarray]:
    read = _form_mesh_file(parts, settings, uv=False)  # the fit: its OBJ answer keeps the file's own lines
    return read.vertices, read.faces


def _form_mesh_file(parts: dict[str, Any], settings: Settings, uv: bool = True) -> uploads.MeshFile:
    """The form's mesh file, read (uploads.MeshFile: vertices, faces, texture coordinates unless uv is False, a
    GLB's parts)."""
    mesh = parts.get("mesh")
    if mesh is None or mesh.filename is None:
        raise InvalidInput("a mesh file is required", "mesh")
    return uploads.mesh_file(mesh.data, mesh.filename, max_vertices=settings.max_vertices,
                             max_faces=settings.max_faces, uv=uv)


def _form_mesh_parts(parts: dict[str, Any], read: uploads.MeshFile) -> list[dict] | None:
    """The mesh file's named parts: an OBJ's objects (or groups), a GLB's placed meshes; None for one part."""
    mesh = parts["mesh"]
    return read.parts if read.parts is not None else obj_parts(mesh.data, mesh.filename, len(read.vertices))


RIG_FORM = ("mesh", "body", "influences", "fit")


def known_form_fields(parts: dict[str, Any], allowed: tuple[str, ...], expected: str | None = None) -> None:
    """A 422 naming the first form field not among `allowed` (`expected` says what is; default: "some of" them):
    the problem's field member is the name itself, as for every other field (it was the quoted name), and the
    detail also quotes it (a space or an empty name shows); cut to 40 characters."""
    unknown = sorted(set(parts) - set(allowed))
    if unknown:
        name = unknown[0]
        raise InvalidInput(f"unknown form field {quoted(name, 40)}; expected {expected or 'some of ' + ', '.join(allowed)}",
                           name[:40])


def rig_arguments(kind: str, content_type: str, data: bytes, settings: Settings,
                  ) -> tuple[Any, Any, str | None, Any, bool, list[dict] | None, np.ndarray | None]:
    """A rig request's body -> (vertices, faces, body preset or None, influences or None, fit, the mesh file's
    named parts or None, the mesh file's texture coordinates of the faces' corners (F, 3, 2) or None), not yet
    checked."""
    if kind == "multipart/form-data":
        parts = parse_form(data, content_type)
        known_form_fields(parts, RIG_FORM, "mesh and some of body, influences, fit")
        read = _form_mesh_file(parts, settings)
        return (read.vertices, read.faces, _text(parts, "body"), _text(parts, "influences"),
                bool(_form_flag(parts, "fit")), _form_mesh_parts(parts, read), read.uv_corners)
    if kind == "application/x-npz":
        z = npz_members(data, ("vertices", "faces", "body", "influences", "fit"), settings, strict=True)
        if "vertices" not in z or "faces" not in z:
            raise InvalidInput("the archive needs arrays 'vertices' and 'faces'", "body")
        return (npz_numbers(z, "vertices"), npz_numbers(z, "faces", integer=True), npz_text(z, "body"),
                npz_scalar(z, "influences"), bool(npz_flag(z, "fit")), None, None)
    doc = _document(data)
    _precheck_mesh(doc, settings)
    req = _model(RigRequest, doc)
    return req.vertices, req.faces, req.body, req.influences, req.fit, None, None


FIT_FIELDS = ("body", "units", "up", "pose")


def fit_arguments(kind: str, content_type: str, data: bytes, settings: Settings) -> dict[str, Any]:
    """A fit request's body (JSON FitRequest; multipart: mesh file + body, units, up, pose ('t', 'a' or JSON
    (24, 3)); npz: vertices, faces + the same as text, pose also as a (24, 3) array) -> keyword arguments of
    handlers.fit, not yet checked; a multipart upload adds `source`: (the mesh file's name, its bytes)."""
    if kind == "multipart/form-data":
        parts = parse_form(data, content_type)
        known_form_fields(parts, ("mesh", *FIT_FIELDS), f"mesh and some of {', '.join(FIT_FIELDS)}")
        v, f = _form_mesh(parts, settings)
        pose: Any = _text(parts, "pose")
        if pose is not None and pose not in ("t", "a"):
            try:
                pose = loads(pose)
            except (ValueError, RecursionError):  # RecursionError: nested deeper than json.loads can take
                raise InvalidInput(f"expected 't', 'a' or a JSON (24, 3) array, got {quoted(pose, 40)}",
                                   "pose") from None
            if not json_reals(pose):  # strict as the JSON request: numpy would read "0" and true as numbers
                raise InvalidInput("expected numbers in nested lists (24, 3), got strings, booleans or nulls",
                                   "pose")
        return {"vertices": v, "faces": f, "body": _text(parts, "body"), "units": _text(parts, "units"),
                "up": _text(parts, "up"), "pose": pose, "source": (parts["mesh"].filename, parts["mesh"].data)}
    if kind == "application/x-npz":
        z = npz_members(data, ("vertices", "faces", *FIT_FIELDS), settings, strict=True)
        if "vertices" not in z or "faces" not in z:
            raise InvalidInput("the archive needs arrays 'vertices' and 'faces'", "body")
        pose = npz_text(z, "pose") if "pose" in z and z["pose"].dtype.kind == "U" else (
            npz_numbers(z, "pose") if "pose" in z else None)
        return {"vertices": npz_numbers(z, "vertices"), "faces": npz_numbers(z, "faces", integer=True),
                "body": npz_text(z, "body"), "units": npz_text(z, "units"), "up": npz_text(z, "up"), "pose": pose}
    doc = _document(data)
    _precheck_mesh(doc, settings)
    req = _model(FitRequest, doc)
    return {"vertices": req.vertices, "faces": req.faces, "body": req.body, "units": req.units, "up": req.up,
            "pose": req.pose}


def animate_request(kind: str, data: bytes, settings: Settings, engine: Engine, content_type: str = "") -> dict:
    """An animate request's body (JSON, an npz of the same arrays, or a multipart form with a motion_file)
    -> a dict shaped like AnimateRequest; an unknown outfit_id and counts over the limits are refused
    before the numbers are validated."""
    if kind == "application/x-npz":
        return _animate_npz(data, settings, engine)
    if kind == "multipart/form-data":
        return _animate_form(data, content_type, settings, engine)
    doc = _document(data)
    outfit_id = doc.get("outfit_id")
    if isinstance(outfit_id, str) and doc.get("outfit") is None:
        _known(outfit_id, engine)
    _precheck_mesh(doc.get("outfit"), settings, "outfit")
    _precheck_motion(doc.get("motion"), settings)
    return _model(AnimateRequest, doc).model_dump()


def _known(outfit_id: str, engine: Engine) -> None:
    if engine.lookup(outfit_id) is None:
        raise unknown_outfit(engine, outfit_id)


ANIMATE_NPZ = ("outfit_id", "vertices", "faces", "poses", "translation", "fps", "clip", "body", "influences", "refine", "fit",
               *REFINE_OPTIONS)


def _animate_npz(data: bytes, settings: Settings, engine: Engine) -> dict:
    """npz members: outfit_id (text) or vertices (N, 3) + faces (F, 3); clip (text) or poses (T, 24, 3) /
    (T, 72) with optional translation (T, 3) and fps; optional body (text); refine (a boolean scalar) and/or
    the refine options as scalars (eps, max_iterations, relief_iterations; any of them turns refinement on)."""
    first = npz_members(data, ("outfit_id",), settings)
    outfit_id = npz_text(first, "outfit_id")
    if outfit_id is not None:
        _known(outfit_id, engine)
    z = npz_members(data, ANIMATE_NPZ, settings, strict=True)
    if (outfit_id is None) == ("vertices" not in z or "faces" not in z):
        raise InvalidInput("give exactly one of 'outfit_id' and the arrays 'vertices' and 'faces'", "body")
    fps = npz_scalar(z, "fps")
    motion = {"clip": npz_text(z, "clip"), "fps": 30.0 if fps is None else float(fps),
              "poses": npz_numbers(z, "poses") if "poses" in z else None,
              "translation": npz_numbers(z, "translation") if "translation" in z else None}
    refine = refine_choice(npz_flag(z, "refine"), npz_options(z))
    request: dict[str, Any] = {"motion": motion, "body": npz_text(z, "body"), "refine": refine,
                               "outfit_id": outfit_id, "outfit": None, "influences": npz_scalar(z, "influences"),
                               "fit": bool(npz_flag(z, "fit"))}
    if outfit_id is None:
        request["outfit"] = {"vertices": npz_numbers(z, "vertices"), "faces": npz_numbers(z, "faces", integer=True)}
    return request


INNER_NPZ = ("inner_vertices", "inner_faces", "thickness")  # the inner layer's members in a refine npz


def _npz_inner(z: dict, field: str = "body") -> dict | None:
    """The inner layer of a refine npz (`INNER_NPZ` members), or None without inner_vertices."""
    if "inner_vertices" not in z:
        if "inner_faces" in z or "thickness" in z:
            raise InvalidInput("inner_faces and thickness need inner_vertices (T, Ni, 3)", field)
        return None
    if "inner_faces" not in z:
        raise InvalidInput("the archive lacks ['inner_faces']", field)
    thickness = npz_scalar(z, "thickness")
    return {"vertices": npz_numbers(z, "inner_vertices"), "faces": npz_numbers(z, "inner_faces", integer=True),
            "thickness": 0.006 if thickness is None else thickness}


def refine_arguments(kind: str, data: bytes, settings: Settings, content_type: str = "",
                     ) -> tuple[Any, Any, dict, str | None, dict | None, dict | None, Any]:
    """A refine request's body (JSON, npz, or a multipart form with a garment npz and a motion_file)
    -> (vertices, faces, motion dict, body preset, options, inner layer {"vertices", "faces", "thickness"} or
    None, rest_vertices or None)."""
    if kind == "multipart/form-data":
        return _refine_form(data, content_type, settings)
    if kind == "application/x-npz":
        names = ("vertices", "faces", "poses", "translation", "fps", "clip", "body", *REFINE_OPTIONS, *INNER_NPZ,
                 "rest_vertices")
        z = npz_members(data, names, settings, strict=True)
        missing = [k for k in ("vertices", "faces") if k not in z] + ([] if "poses" in z or "clip" in z else ["poses"])
        if missing:
            raise InvalidInput(f"the archive lacks {missing}", "body")
        fps = npz_scalar(z, "fps")
        motion = {"clip": npz_text(z, "clip"), "fps": 30.0 if fps is None else float(fps),
                  "poses": npz_numbers(z, "poses") if "poses" in z else None,
                  "translation": npz_numbers(z, "translation") if "translation" in z else None}
        return (npz_numbers(z, "vertices"), npz_numbers(z, "faces", integer=True), motion, npz_text(z, "body"),
                npz_options(z), _npz_inner(z), npz_numbers(z, "rest_vertices") if "rest_vertices" in z else None)
    doc = _document(data)
    inner = doc.get("inner")
    for pre, part in (("", doc), ("inner.", inner if isinstance(inner, dict) else {})):
        _count(part.get("vertices"), settings.max_frames, "frames", f"{pre}vertices")
        frames = part.get("vertices")
        if isinstance(frames, list) and frames:
            _count(frames[0], settings.max_vertices, "vertices", f"{pre}vertices")
        _count(part.get("faces"), settings.max_faces, "faces", f"{pre}faces")
    _count(doc.get("rest_vertices"), settings.max_vertices, "vertices", "rest_vertices")
    _precheck_motion(doc.get("motion"), settings)
    d = _model(RefineRequest, doc).model_dump()
    return d["vertices"], d["faces"], d["motion"], d["body"], d["options"], d["inner"], d["rest_vertices"]


# ---- multipart forms carrying a motion file ------------------------------------------------------

ANIMATE_FORM = ("motion_file", "outfit_id", "fps", "body", "up", "influences", "refine", *REFINE_OPTIONS)
REFINE_FORM = ("garment", "motion_file", "fps", "body", "up", *REFINE_OPTIONS)
_OPTION_TYPES: dict[str, type[float] | type[int]] = {"eps": float, "max_iterations": int, "relief_iterations": int}


def _form(data: bytes, content_type: str, allowed: tuple[str, ...]) -> dict[str, Any]:
    parts = parse_form(data, content_type)
    known_form_fields(parts, allowed)
    if "motion_file" not in parts:
        raise InvalidInput("a motion file is required: a CMU-named BVH or an AMASS-style npz", "motion_file")
    return parts


def _text(parts: dict[str, Any], name: str) -> str | None:
    part = parts.get(name)
    return None if part is None else part.data.decode("utf-8", "replace").strip()


MAX_FORM_NUMBER_CHARS = 64  # a form field's number as text, sign and exponent included
_FORM_NUMBER = {float: re.compile(r"-?(?:0|[1-9][0-9]*)(?:\.[0-9]+)?(?:[eE][-+]?[0-9]+)?"), int: re.compile(r"-?[0-9]+")}


def _form_number(text: str, kind: type[float] | type[int], field: str) -> float | int:
    """A form field's number as JSON writes one (an integer for int): Python's own float() and int() also read
    "2_0" as 20, "nan" and "infinity", which are not numbers a client means."""
    if not _FORM_NUMBER[kind].fullmatch(text):
        raise InvalidInput(f"expected {'an integer' if kind is int else 'a number'}, got {quoted(text, 40)}", field)
    if len(text) > MAX_FORM_NUMBER_CHARS:  # int() refuses over 4,300 digits (a ValueError, was a 500)
        raise InvalidInput(f"expected a number of at most {MAX_FORM_NUMBER_CHARS} characters, got {len(text)}", field)
    return kind(text)


def _form_fps(parts: dict[str, Any]) -> float:
    text = _text(parts, "fps")
    if text is None:
        return 30.0
    fps = float(_form_number(text, float, "fps"))
    if not 0 < fps <= 1000:
        raise InvalidInput(f"must be in (0, 1000], got {fps}", "fps")
    return fps


def _form_up(parts: dict[str, Any]) -> str | None:
    up = _text(parts, "up")
    if up not in (None, "y", "z"):
        raise InvalidInput(f"expected 'y' or 'z', got {quoted(up, 40)}", "up")
    return up


def _form_options(parts: dict[str, Any]) -> dict | None:
    given: dict[str, Any] = {}
    for key in REFINE_OPTIONS:
        text = _text(parts, key)
        if text is not None:
            given[key] = _form_number(text, _OPTION_TYPES.get(key, float), key)
    return _refine_options(given)


def _form_motion(parts: dict[str, Any], body: str, settings: Settings) -> dict:
    poses, trans, fps = uploads.motion_from_file(
        parts["motion_file"].data, body, fps=_form_fps(parts), up=_form_up(parts), max_frames=settings.max_frames,
        max_decoded_bytes=settings.max_decoded_bytes)
    return {"clip": None, "poses": poses, "translation": trans, "fps": fps}


def _animate_form(data: bytes, content_type: str, settings: Settings, engine: Engine) -> dict:
    """Form fields: motion_file (a BVH or npz file), outfit_id, and optionally fps (default 30: the motion is
    resampled to it), body, up (y or z; default: detected), influences, refine (true/false) and the refine
    options (eps, max_iterations, relief_iterations; any of them turns refinement on)."""
    parts = _form(data, content_type, ANIMATE_FORM)
    outfit_id = _text(parts, "outfit_id")
    if not outfit_id:
        raise InvalidInput("an outfit_id is required with a motion_file (rig the outfit first)", "outfit_id")
    _known(outfit_id, engine)
    outfit = engine.lookup(outfit_id)
    assert outfit is not None
    body = _text(parts, "body")
    if body not in (None, outfit.body):
        raise InvalidInput(f"outfit {outfit_id} was rigged on body {outfit.body!r}", "body")
    refine = refine_choice(_form_flag(parts, "refine"), _form_options(parts))
    return {"motion": _form_motion(parts, outfit.body, settings), "body": body, "refine": refine,
            "outfit_id": outfit_id, "outfit": None, "influences": _text(parts, "influences")}


def _refine_form(data: bytes, content_type: str, settings: Settings,
                 ) -> tuple[Any, Any, dict, str | None, dict | None, dict | None, Any]:
    """Form fields: garment (an npz with vertices (T, N, 3) and faces (F, 3), optionally an inner layer:
    inner_vertices (T, Ni, 3), inner_faces, thickness, or the rest shape rest_vertices (N, 3)), motion_file (a BVH or
    npz file, resampled to fps, default 30: it must give T frames), and optionally body, up and the refine options."""
    from drape.service.handlers import check_body

    parts = _form(data, content_type, REFINE_FORM)
    garment = parts.get("garment")
    if garment is None:
        raise InvalidInput("a garment npz with vertices (T, N, 3) and faces (F, 3) is required", "garment")
    try:
        z = decode_npz(garment.data, ("vertices", "faces", *INNER_NPZ, "rest_vertices"),
                       max_bytes=settings.max_decoded_bytes)
    except NpzTooLarge as exc:
        raise LimitExceeded(str(exc), "garment") from exc
    except ValueError as exc:
        raise MalformedInput(str(exc), "garment") from exc
    missing = [k for k in ("vertices", "faces") if k not in z]
    if missing:
        raise InvalidInput(f"the archive lacks {missing}", "garment")
    body = check_body(_text(parts, "body"))
    motion = _form_motion(parts, body, settings)
    return (npz_numbers(z, "vertices"), npz_numbers(z, "faces", integer=True), motion, body, _form_options(parts),
            _npz_inner(z, "garment"), npz_numbers(z, "rest_vertices") if "rest_vertices" in z else None)


# ---- the garment routes (intrinsic space) --------------------------------------------------------

GARMENT_FORM = ("motion_file", "fps", "up", "request")
GARMENT_NPZ = {
    "encode": ("vertices", "frame"),
    "animate": ("vertex_frames", "vertices", "latent_frames", "latents", "match_keyframes", "refine", *REFINE_OPTIONS),
    "sample": ("count", "seed", "frame"),
}
MOTION_NPZ = ("poses", "translation", "fps", "clip")
GARMENT_REQUESTS: dict[str, type[BaseModel]] = {"encode": EncodeRequest, "animate": KeyframeAnimateRequest,
                                                "sample": SampleRequest}
GARMENT_FIELDS: dict[str, type[BaseModel]] = {"encode": EncodeFields, "animate": KeyframeFields,
                                              "sample": SampleFields}


def garment_request(route: str, kind: str, data: bytes, settings: Settings, body: str, content_type: str = "") -> dict:
    """A garment route's body (route: "encode", "animate" or "sample") -> a dict shaped like its request model
    (EncodeRequest, KeyframeAnimateRequest, SampleRequest), the arrays not yet checked against the garment.

    JSON: the model itself. npz: the motion's members (clip or poses, translation, fps) and the route's:
    encode: vertices (N, 3), frame (integer scalar); sample: count, seed, frame (integer scalars); animate:
    vertex_frames (Kv,) with vertices (Kv, N, 3) and/or latent_frames (Kl,) with latents (Kl, Z) (keyframes
    numbered vertex ones first), match_keyframes (boolean scalar), refine (boolean scalar) and/or the refine
    options as scalars. A multipart form:
    motion_file (a BVH or AMASS npz, retargeted onto the garment's `body`), fps, up, and `request`: the JSON
    request without its motion."""
    if kind == "application/x-npz":
        return _garment_npz(route, data, settings)
    if kind == "multipart/form-data":
        parts = _form(data, content_type, GARMENT_FORM)
        text = parts.get("request")
        doc = _document(text.data, "request") if text is not None else {}
        _precheck_garment(route, doc, settings)
        request = _model(GARMENT_FIELDS[route], doc).model_dump()
        request["motion"] = _form_motion(parts, body, settings)
        return request
    doc = _document(data)
    _precheck_garment(route, doc, settings)
    _precheck_motion(doc.get("motion"), settings)
    return _model(GARMENT_REQUESTS[route], doc).model_dump()


def _precheck_garment(route: str, doc: dict, settings: Settings) -> None:
    """Counts over the limits, before the models validate every number."""
    if route == "encode":
        _count(doc.get("vertices"), settings.max_vertices, "vertices", "vertices")
    elif route == "animate":
        keys = doc.get("keyframes")
        _count(keys, settings.max_frames, "keyframes", "keyframes")
        for i, key in enumerate(keys if isinstance(keys, list) else []):
            if isinstance(key, dict):
                _count(key.get("vertices"), settings.max_vertices, "vertices", f"keyframes[{i}].vertices")


def _npz_motion(z: dict[str, np.ndarray]) -> dict:
    fps = npz_scalar(z, "fps")
    return {"clip": npz_text(z, "clip"), "fps": 30.0 if fps is None else float(fps),
            "poses": npz_numbers(z, "poses") if "poses" in z else None,
            "translation": npz_numbers(z, "translation") if "translation" in z else None}


def npz_integer(z: dict[str, np.ndarray], name: str) -> int | None:
    """An integer scalar member, or None when absent."""
    if name not in z:
        return None
    a = z[name]
    if a.shape != () or a.dtype.kind not in "iu":
        raise InvalidInput(f"expected an integer scalar, got dtype {a.dtype} and shape {a.shape}", name)
    return int(a)


def _garment_npz(route: str, data: bytes, settings: Settings) -> dict:
    z = npz_members(data, (*MOTION_NPZ, *GARMENT_NPZ[route]), settings, strict=True)
    request: dict[str, Any] = {"motion": _npz_motion(z)}
    if route == "encode":
        if "vertices" not in z or "frame" not in z:
            raise InvalidInput("the archive needs 'vertices' (N, 3) and 'frame' (an integer scalar)", "body")
        request.update(vertices=npz_numbers(z, "vertices"), frame=npz_integer(z, "frame"))
    elif route == "sample":
        if "count" not in z:
            raise InvalidInput("the archive needs 'count' (an integer scalar)", "body")
        request["count"] = npz_integer(z, "count")
        for name in ("seed", "frame"):
            if name in z:
                request[name] = npz_integer(z, name)
    else:
        keyframes: list[dict[str, Any]] = []
        for frames_name, values_name, key in (("vertex_frames", "vertices", "vertices"),
                                              ("latent_frames", "latents", "latent")):
            if (frames_name in z) != (values_name in z):
                raise InvalidInput(f"give '{frames_name}' and '{values_name}' together", "body")
            if frames_name not in z:
                continue
            frames = npz_numbers(z, frames_name, integer=True)
            values = npz_numbers(z, values_name)
            if frames.ndim != 1 or values.ndim < 1 or len(values) != len(frames):
                raise InvalidInput(f"'{frames_name}' must be (K,) and '{values_name}' hold K keyframes, got shapes "
                                   f"{frames.shape} and {values.shape}", values_name)
            if len(frames) > settings.max_frames:
                raise LimitExceeded(f"{len(frames)} keyframes exceed the limit of {settings.max_frames}", frames_name)
            keyframes += [{"frame": int(f), key: v, NPZ_MEMBERS_KEY: (frames_name, values_name, j)}
                          for j, (f, v) in enumerate(zip(frames, values, strict=True))]
        if not keyframes:
            raise InvalidInput("give at least one keyframe: 'vertex_frames' with 'vertices' and/or 'latent_frames' "
                               "with 'latents'", "keyframes")
        refine = refine_choice(npz_flag(z, "refine"), npz_options(z))
        request.update(keyframes=keyframes, refine=refine)
        match = npz_flag(z, "match_keyframes")
        if match is not None:
            request["match_keyframes"] = match
    return request


# ---- the layer routes ----------------------------------------------------------------------------

LAYERS_FORM = ("motion_file", "fps", "up", "request")


def layers_request(data: bytes, settings: Settings, engine: Engine, kind: str = "", content_type: str = "",
                   ) -> dict:
    """A layers animate request -> its fields as a dict shaped like LayersAnimateRequest. JSON: the model itself.
    A multipart form: motion_file (a BVH or AMASS npz, retargeted onto the combination's body), fps, up, and
    `request`: the JSON request without its motion (LayersFields); the combination is checked (404 / 422, as
    the JSON request's) before the file is imported."""
    from drape.schemas.layers import LayersAnimateRequest, LayersFields
    from drape.service.layers import find_combination

    if kind == "multipart/form-data":
        parts = _form(data, content_type, LAYERS_FORM)
        text = parts.get("request")
        if text is None:
            raise InvalidInput("the request's fields are required as JSON text (inner, outer, thickness, refine)",
                               "request")
        request = _model(LayersFields, _document(text.data, "request")).model_dump()
        combo = find_combination(engine, request["inner"], request["outer"])
        request["motion"] = _form_motion(parts, combo.inner.body, settings)
        return request
    doc = _document(data)
    _precheck_motion(doc.get("motion"), settings)
    return _model(LayersAnimateRequest, doc).model_dump()
