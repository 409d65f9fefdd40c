"""drape.Client and drape.AsyncClient: the same calls, one blocking, one async; shared request logic."""

from __future__ import annotations

import json
import numbers
import os
import re
import warnings
from collections.abc import AsyncIterator, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, overload
from urllib.parse import quote

import httpx
import numpy as np

from drape.schemas import WARNINGS_HEADER
from drape.schemas.binary import FRAMES, NPZ, FrameDecoder, FrameReader, decode_npz, encode_npz
from drape.schemas.catalog import BodyList, BodyRegistered, Health, MotionList
from drape.schemas.garments import GarmentList
from drape.schemas.layers import LayerList
from drape.schemas.models import ModelInfo, ModelList
from drape.schemas.outfits import RefineOptions

OutfitLike = Any  # path | (vertices, faces) | object with .vertices/.faces
Format = Literal["array", "glb", "pc2"]  # frames as one (T, N, 3) array, or the file bytes of an engine format
_FILE_TYPES = {"glb": "model/gltf-binary", "pc2": "application/x-pc2"}
FitFormat = Literal["array", "obj"]  # the fit as a FitResult, or the bytes of an OBJ file
RigFormat = Literal["array", "glb"]  # the rig's arrays (a RigResult), or the bytes of a GLB
MotionLike = Any  # clip name | poses array | object or mapping with poses/trans/fps | MotionFile | Path of a file
# the collision refinement post step: on/off, or its options (RefineOptions or a mapping of its fields: eps,
# max_iterations, relief_iterations), which turn it on; fields left out take the service's defaults
RefineLike = bool | RefineOptions | Mapping[str, Any]
# a keyframe: {"frame": f, "vertices": (N, 3)} or {"frame": f, "latent": (Z,)}, or a (frame, array) pair whose
# array is vertices (N, 3) (2-D) or a latent (Z,) (1-D)
KeyframeLike = Mapping[str, Any] | tuple[int, Any]


class DrapeAPIError(Exception):
    """An error answer from the service, carrying its RFC 9457 problem details: status, type, title, detail,
    field (the request's field that is wrong, e.g. 'motion.poses'; None when the error is not about one), and
    retry_after (seconds, from a 503's Retry-After; None otherwise)."""

    def __init__(self, status: int, type: str, title: str, detail: str, *, field: str | None = None,
                 retry_after: float | None = None):
        super().__init__(f"{status} {title}: {detail}")
        self.status, self.type, self.title, self.detail = status, type, title, detail
        self.field, self.retry_after = field, retry_after


@dataclass(frozen=True)
class RigResult:
    """outfit_id; skinning_weights (N, 24); blend_shapes (P, N, 3) m; the skeleton (names, parents, rest joints
    (24, 3)); diagnostics: where the mesh sits on the body at rest (see its warnings)."""

    outfit_id: str
    skinning_weights: np.ndarray
    blend_shapes: np.ndarray
    joint_names: list[str]
    parents: np.ndarray
    rest_joints: np.ndarray
    diagnostics: dict = field(default_factory=dict)  # inside_share, distance_mm, bbox, warnings (sentences)
    fit: FitResult | None = None  # with rig(..., fit=True): the fitted mesh the rig belongs to
    parts: list[dict] | None = None  # an uploaded OBJ's objects in file order: {"name", "start", "stop"} vertex ranges


@dataclass(frozen=True)
class FitResult:
    """A garment fitted onto a body at rest: vertices (N, 3) float32 m, Y-up; faces (F, 3) int32; transform
    (4, 4): the similarity applied before the push-out (units, up axis, facing, translation); report: units and
    up (given or inferred), inside_before / inside_after (shares at rest), max_move_mm, mean_move_mm,
    max_stretch_mm, warnings (sentences: units or up given against what the mesh says)."""

    vertices: np.ndarray
    faces: np.ndarray
    transform: np.ndarray
    report: dict


@dataclass(frozen=True)
class GarmentTemplate:
    """A served garment template in rest pose on its body: vertices (N, 3) float32 m, faces (F, 3) int32."""

    name: str
    body: str
    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class BodyArrays:
    """A body's rest mesh and skeleton (a preset or a registered body_id): vertices (V, 3) float32 m, T-pose, +Y
    up; faces (F, 3) int32; weights (V, 24) float32, rows summing to 1; joints (24, 3) float32 m; parents (24,)
    int, -1 for the root; joint_names: 24 names in SMPL order."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    joints: np.ndarray
    parents: np.ndarray
    joint_names: list[str]


@dataclass(frozen=True)
class DesignSamples:
    """Design candidates: latents (count, Z) float32 and their shapes (count, N, 3) float32 m, world space at the
    frame they were decoded at."""

    latents: np.ndarray
    vertices: np.ndarray


@dataclass(frozen=True)
class LayerFrames:
    """Two garments worn together along a motion: inner_vertices (T, Ni, 3) and outer_vertices (T, No, 3)
    float32 m, world space; their faces (F, 3) int32; the templates' names; frames per second."""

    inner: str
    outer: str
    fps: float
    inner_vertices: np.ndarray
    inner_faces: np.ndarray
    outer_vertices: np.ndarray
    outer_faces: np.ndarray


@dataclass(frozen=True)
class MotionFile:
    """A motion capture file for the service to import onto the garment's body: a CMU-named BVH or an AMASS-style
    npz (docs/motion_import.md). fps: the frame rate it is resampled to (None: the service's 30); up: the
    file's up axis, "y" or "z" (None: detected). A bare Path as `motion` is MotionFile(path)."""

    path: str | os.PathLike
    fps: float | None = None
    up: Literal["y", "z"] | None = None


MOTION_FILE_SUFFIXES = (".bvh", ".npz")  # what the service imports; no clip name ends so


def _motion_file(motion: MotionLike) -> MotionFile | None:
    """The motion as a MotionFile when it is a file (a MotionFile or a Path), else None."""
    if isinstance(motion, MotionFile):
        return motion
    return MotionFile(motion) if isinstance(motion, os.PathLike) else None


def _file_form(motion: MotionFile, fields: Mapping[str, Any]) -> dict[str, Any]:
    """httpx arguments of a multipart form: the file as `motion_file`, its fps and up, and `fields` (text;
    None: left out)."""
    path = Path(motion.path)
    data = {"fps": motion.fps, "up": motion.up, **fields}
    return {"files": {"motion_file": (path.name, path.read_bytes())},
            "data": {k: str(v) for k, v in data.items() if v is not None}}


def _refine_choice(refine: RefineLike) -> tuple[bool, dict[str, Any]]:
    """(on, the options given): True / False, or RefineOptions or a mapping of its fields (validated here; they
    turn refinement on; fields left out are not sent, so the service's defaults apply)."""
    if isinstance(refine, Mapping):
        refine = RefineOptions.model_validate(dict(refine))
    if isinstance(refine, RefineOptions):
        return True, refine.model_dump(exclude_unset=True)
    return bool(refine), {}


def _refine_json(refine: RefineLike) -> bool | dict[str, Any]:
    """refine as a JSON request carries it: a boolean, or the options given (an object)."""
    on, options = _refine_choice(refine)
    return options if options else on


def _refine_members(refine: RefineLike) -> dict[str, np.ndarray]:
    """refine as an npz request carries it: a boolean scalar `refine` and the options given as scalars."""
    on, options = _refine_choice(refine)
    return {"refine": np.array(on), **{k: np.array(v) for k, v in options.items()}}


def _layers_request(inner: str, outer: str, motion: MotionLike, thickness: float,
                    refine: RefineLike) -> dict[str, Any]:
    """The layers animate request's httpx arguments: JSON with the motion as a clip name or poses; with a motion
    file (a MotionFile or Path: BVH or AMASS npz), a multipart form with the file as `motion_file` (the server
    retargets it onto the combination's body) and the rest of the request as JSON text in `request`."""
    if isinstance(thickness, str | bytes | bool | np.bool_):  # float() read "0.006" and True
        raise ValueError(f"thickness: expected a number of metres, got {thickness!r}")
    if not np.isfinite(float(thickness)):  # json.dumps raised 'Out of range float values are not JSON compliant'
        raise ValueError(f"thickness: expected a finite number of metres, got {thickness!r}")
    fields = {"inner": inner, "outer": outer, "thickness": float(thickness), "refine": _refine_json(refine)}
    file = _motion_file(motion)
    if file is not None:
        return _motion_form(file, fields)
    if isinstance(motion, bytes):
        raise ValueError("animate_layers takes a clip name, poses or a motion file (MotionFile or Path), not bytes")
    arrays = _motion_arrays(motion)
    m: dict[str, Any] = ({"clip": str(arrays["clip"])} if "clip" in arrays else
                         {"poses": _finite(arrays["poses"], "motion poses").reshape(len(arrays["poses"]), -1).tolist(),
                          **({"translation": _finite(arrays["translation"], "motion translation").tolist()}
                             if "translation" in arrays else {}),
                          **({"fps": float(arrays["fps"])} if "fps" in arrays else {})})
    return {"json": {**fields, "motion": m}}


def _layer_frames(response: httpx.Response) -> LayerFrames:
    _raise_for(response)
    z = decode_npz(response.content)
    return LayerFrames(str(z["inner"]), str(z["outer"]), float(z["fps"]), z["inner_vertices"], z["inner_faces"],
                       z["outer_vertices"], z["outer_faces"])


class DrapeWarning(UserWarning):
    """The service did as asked but says something looks wrong (an answer's Drape-Warnings header), e.g. a motion
    file whose skeleton contradicts the `up` given. Raised with `warnings.warn`: shown once per place by default;
    `warnings.simplefilter("error", DrapeWarning)` makes them errors."""


def _warn_for(response: httpx.Response) -> None:
    """Each sentence of a successful answer's Drape-Warnings header, as a DrapeWarning."""
    text = response.headers.get(WARNINGS_HEADER)
    if not text:
        return
    try:
        sentences = json.loads(text)
    except ValueError:
        sentences = [text]
    for sentence in sentences if isinstance(sentences, list) else [sentences]:
        warnings.warn(f"drape: {sentence}", DrapeWarning, stacklevel=4)


def _raise_for(response: httpx.Response) -> None:
    """DrapeAPIError for an error answer: its problem details, or (an answer that is not a problem: a proxy's
    HTML page, other JSON) the reason phrase as title and the start of the body as detail. A successful answer's
    warnings are raised as DrapeWarnings."""
    if response.status_code < 400:
        _warn_for(response)
        return
    try:
        p = response.json()
    except ValueError:
        p = None

    def text(key: str) -> str | None:
        value = p.get(key) if isinstance(p, dict) else None
        return value if isinstance(value, str) else None

    detail = text("detail")
    try:
        retry_after: float | None = float(response.headers["retry-after"])
    except (KeyError, ValueError):
        retry_after = None
    raise DrapeAPIError(response.status_code, text("type") or "", text("title") or response.reason_phrase,
                        response.text[:500] if detail is None else detail, field=text("field"),
                        retry_after=retry_after)


def _reals(value: Any, dtype: type, name: str) -> np.ndarray:
    """An array of real numbers as `dtype`: complex, text or object values are a ValueError naming `name` (numpy
    dropped an imaginary part with a warning and sent the rest). An object array of real numbers (as a pandas
    column of mixed ints and floats gives) is read as the numbers; text in it is refused, never parsed."""
    a = np.asarray(value)
    if a.dtype.kind == "O" and all(isinstance(x, numbers.Real) for x in a.ravel()):
        try:
            a = a.astype(np.float64)
        except OverflowError:
            raise ValueError(f"{name}: holds a number beyond float64") from None
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{name}: expected real numbers, got dtype {a.dtype}")
    return a.astype(dtype)


def _finite(a: np.ndarray, name: str) -> np.ndarray:
    """`a` unchanged; NaN or infinite values are a ValueError naming `name` (a JSON request cannot carry them:
    json.dumps raised 'Out of range float values are not JSON compliant')."""
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or infinite values")
    return a


def _indices(value: Any, name: str) -> np.ndarray:
    """Integer indices as int64: floats that are not whole numbers are a ValueError naming `name` (they were
    truncated: faces + 0.7 rigged as the faces)."""
    a = np.asarray(value)
    if a.dtype.kind == "f" and not (np.isfinite(a).all() and np.array_equal(a, np.round(a))
                                    and (a.size == 0 or np.abs(a).max() < 2**53)):
        raise ValueError(f"{name}: expected integer indices, got values that are not whole numbers (or beyond 2**53)")
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{name}: expected integer indices, got dtype {a.dtype}")
    return a.astype(np.int64)


def _integer(value: Any, name: str) -> int:
    """A whole number (an int, or a float with no fraction): 2.9 is a ValueError naming `name`, not 2."""
    if isinstance(value, np.ndarray) and value.ndim == 0:  # a 0-d array, as numpy's reductions give
        value = value.item()
    if isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_):
        return int(value)
    if isinstance(value, float | np.floating) and np.isfinite(value) and float(value).is_integer():
        return int(value)
    raise ValueError(f"{name}: expected an integer, got {value!r}")


def _mesh_arrays(outfit: OutfitLike) -> tuple[np.ndarray, np.ndarray] | None:
    """Arrays of an in-memory outfit, or None for a file path."""
    if isinstance(outfit, str | os.PathLike):
        return None
    if hasattr(outfit, "vertices") and hasattr(outfit, "faces"):
        vertices, faces = outfit.vertices, outfit.faces
    else:
        vertices, faces = outfit
    return _finite(_reals(vertices, np.float32, "outfit vertices"), "outfit vertices"), _indices(faces, "outfit faces")


def _motion_arrays(motion: MotionLike) -> dict[str, np.ndarray]:
    """A motion as the request's arrays: clip (a name) or poses, fps and translation if given."""
    if isinstance(motion, str):
        if motion.lower().endswith(MOTION_FILE_SUFFIXES):  # a 404 'unknown clip' said nothing of files
            raise ValueError(f"motion: {motion!r} is taken as a clip name, and names no clip; to upload the file, "
                             f"pass Path({motion!r}) or MotionFile({motion!r}, fps=..., up=...)")
        return {"clip": np.array(motion)}
    if isinstance(motion, np.ndarray | list):
        return {"poses": _reals(motion, np.float64, "motion poses")}
    get = motion.get if isinstance(motion, Mapping) else (lambda k, d=None: getattr(motion, k, d))
    poses = get("poses", None)
    if poses is None and isinstance(get("clip", None), str):  # the wire's own motion object: {"clip": name}
        return {"clip": np.array(get("clip"))}
    if poses is None:
        raise ValueError("motion: give a clip name, poses, a mapping or object with poses (or a clip), or a "
                         f"MotionFile / Path of a motion file; got {type(motion).__name__} without poses")
    trans = get("translation", None)
    trans = get("trans", None) if trans is None else trans
    fps = get("fps", None)  # None: the service's 30; any other value is sent as given (0 is the service's 422)
    out = {"poses": _reals(poses, np.float64, "motion poses"), "fps": np.array(30.0 if fps is None else float(fps))}
    if trans is not None:
        out["translation"] = _reals(trans, np.float64, "motion translation")
    return out


def _mesh_request(outfit: OutfitLike, **fields: Any) -> dict:
    """httpx arguments sending a mesh (a file path: multipart `mesh`; arrays: JSON) with the given fields
    (None: left out)."""
    given = {k: v for k, v in fields.items() if v is not None}
    arrays = _mesh_arrays(outfit)
    if arrays is None:
        path = Path(outfit)
        return {"files": {"mesh": (path.name, path.read_bytes())},
                "data": {k: (str(v).lower() if isinstance(v, bool) else v if isinstance(v, str) else json.dumps(v))
                         for k, v in given.items()}}
    return {"json": {"vertices": arrays[0].tolist(), "faces": arrays[1].tolist(), **given}}


def _rig_request(outfit: OutfitLike, body: str, influences: int, fit: bool = False) -> dict:
    return _mesh_request(outfit, body=body, influences=influences, fit=fit or None)


def _fit_result(z: dict, prefix: str = "") -> FitResult:
    return FitResult(z[f"{prefix}vertices"], z[f"{prefix}faces"], z[f"{prefix}transform"],
                     json.loads(str(z[f"{prefix}report"])))


def _fit_request(outfit: OutfitLike, body: str, units: str | None, up: str | None, pose: Any) -> dict:
    pose = pose if isinstance(pose, str) else _finite(_reals(pose, float, "pose"), "pose").tolist()
    return _mesh_request(outfit, body=body, units=units, up=up, pose=pose)


def _fit_accept(format: str) -> str:
    if format not in ("array", "obj"):
        raise ValueError(f"format must be 'array' or 'obj', not {format!r}")
    return NPZ if format == "array" else "model/obj"


def _fit_answer(response: httpx.Response, format: str = "array") -> FitResult | bytes:
    _raise_for(response)
    return _fit_result(decode_npz(response.content)) if format == "array" else response.content


BodyLike = Any  # path to a .glb / .gltf / .npz, the file's bytes, or a mapping of the body's arrays


def _body_request(body: BodyLike, joint_map: Mapping[str, str] | None, rest_pose: Any) -> dict:
    """httpx arguments registering a body: a multipart form with `body_file` (+ joint_map, rest_pose as JSON)."""
    if isinstance(body, str | os.PathLike):
        path = Path(body)
        name, data = path.name, path.read_bytes()
    elif isinstance(body, bytes | bytearray):
        name, data = ("body.glb" if bytes(body[:4]) == b"glTF" else "body.npz"), bytes(body)
    else:
        name, data = "body.npz", encode_npz({k: np.asarray(v) for k, v in body.items()})
    fields = {"joint_map": json.dumps(dict(joint_map)) if joint_map is not None else None,
              "rest_pose": json.dumps(np.asarray(rest_pose, float).tolist()) if rest_pose is not None else None}
    return {"files": {"body_file": (name, data)}, "data": {k: v for k, v in fields.items() if v is not None}}


def _registered(response: httpx.Response) -> BodyRegistered:
    _raise_for(response)
    return BodyRegistered.model_validate(response.json())


def _body_arrays(name: str, response: httpx.Response) -> BodyArrays:
    _raise_for(response)
    z = decode_npz(response.content)
    return BodyArrays(name=name, vertices=z["vertices"], faces=z["faces"], weights=z["weights"], joints=z["joints"],
                      parents=z["parents"], joint_names=[str(n) for n in z["joint_names"]])


def _rig_accept(format: str) -> str:
    """The rig's Accept for `format`, checked before anything is sent."""
    if format not in ("array", "glb"):
        raise ValueError(f"format must be 'array' or 'glb', not {format!r}")
    return NPZ if format == "array" else _FILE_TYPES["glb"]


def _rig_answer(response: httpx.Response, format: str) -> RigResult | bytes:
    if format == "array":
        return _rig_result(response)
    _raise_for(response)
    return response.content


def _rig_result(response: httpx.Response) -> RigResult:
    _raise_for(response)
    z = decode_npz(response.content)
    return RigResult(str(z["outfit_id"]), z["skinning_weights"], z["blend_shapes"],
                     [str(n) for n in z["joint_names"]], z["parents"], z["rest_joints"],
                     json.loads(str(z["diagnostics"])) if "diagnostics" in z else {},
                     _fit_result(z, "fit_") if "fit_vertices" in z else None,
                     json.loads(str(z["parts"])) if "parts" in z else None)


def _animate_request(outfit_id: str | None, arrays: tuple | None, motion: MotionLike, body: str | None,
                     influences: int | None, fit: bool, refine: RefineLike) -> dict:
    """The animate request's httpx arguments: an npz body; with a motion file (a MotionFile or Path: BVH or
    AMASS npz), a multipart form with the file as `motion_file` (the server retargets it onto the outfit's
    body) and an outfit_id (the form has no fit: a mesh is rigged, and fitted, first)."""
    file = _motion_file(motion)
    if file is not None:
        on, options = _refine_choice(refine)
        fields = {"outfit_id": outfit_id, "refine": str(on).lower(), "body": body,
                  "influences": None if influences is None else int(influences), **options}
        return {**_file_form(file, fields), "headers": {}}
    return {"content": _animate_npz(outfit_id, arrays, motion, body, influences, fit, refine),
            "headers": {"Content-Type": NPZ}}


def _animate_npz(outfit_id: str | None, arrays: tuple | None, motion: MotionLike, body: str | None,
                 influences: int | None, fit: bool, refine: RefineLike) -> bytes:
    """The animate request as an npz: the motion's arrays in binary instead of JSON text."""
    req: dict[str, np.ndarray] = {**_motion_arrays(motion), **_refine_members(refine)}
    if outfit_id is not None:
        req["outfit_id"] = np.array(outfit_id)
    elif arrays is not None:
        req["vertices"], req["faces"] = arrays
    if body is not None:
        req["body"] = np.array(body)
    if influences is not None:
        req["influences"] = np.array(int(influences))
    if fit:
        req["fit"] = np.array(True)
    return encode_npz(req)


def _refine_request(vertices: np.ndarray, faces: np.ndarray, motion: MotionLike, body: str, eps: float | None,
                    max_iterations: int | None, relief_iterations: int | None,
                    inner: tuple[np.ndarray, np.ndarray] | None = None, thickness: float | None = None,
                    rest_vertices: np.ndarray | None = None) -> dict:
    """The refine request's httpx arguments: an npz (binary float32 vertices instead of JSON text, about a tenth
    of the bytes); with a motion file (a MotionFile or Path), a multipart form with the garment (and inner layer)
    as the npz `garment` beside `motion_file` (the server imports it; it must give T frames). Options left None
    are not sent: the service applies its defaults."""
    garment: dict[str, np.ndarray] = {"vertices": _reals(vertices, np.float32, "vertices"),
                                      "faces": _indices(faces, "faces")}
    if inner is not None:
        garment["inner_vertices"] = _reals(inner[0], np.float32, "inner vertices")
        garment["inner_faces"] = _indices(inner[1], "inner faces")
    if thickness is not None:
        garment["thickness"] = np.array(float(thickness))
    if rest_vertices is not None:
        garment["rest_vertices"] = np.asarray(rest_vertices, np.float64)
    options = {k: v for k, v in (("eps", None if eps is None else float(eps)),
                                 ("max_iterations", None if max_iterations is None else int(max_iterations)),
                                 ("relief_iterations", None if relief_iterations is None else int(relief_iterations)))
               if v is not None}
    file = _motion_file(motion)
    if file is not None:
        form = _file_form(file, {"body": body, **options})
        form["files"]["garment"] = ("garment.npz", encode_npz(garment))
        return form
    return {"content": encode_npz({**garment, **_motion_arrays(motion), "body": np.array(body),
                                   **{k: np.array(v) for k, v in options.items()}}),
            "headers": {"Content-Type": NPZ}}


def _garment_path(name: str, route: str = "") -> str:
    return f"/v1/garments/{quote(name, safe='')}" + (f"/{route}" if route else "")


def _keyframe_arrays(keyframes: Sequence[KeyframeLike]) -> dict[str, np.ndarray]:
    """Keyframes as the animate request's npz members: vertex_frames (Kv,) + vertices (Kv, N, 3) and
    latent_frames (Kl,) + latents (Kl, Z)."""
    shapes: list[tuple[int, np.ndarray]] = []
    latents: list[tuple[int, np.ndarray]] = []
    for key in keyframes:
        if isinstance(key, Mapping):
            if ("vertices" in key) == ("latent" in key):
                raise ValueError("a keyframe mapping needs 'frame' and exactly one of 'vertices' and 'latent'")
            frame, value, is_latent = key["frame"], key.get("latent", key.get("vertices")), "latent" in key
        else:
            frame, value = key
            is_latent = np.ndim(value) == 1
        (latents if is_latent else shapes).append((_integer(frame, "keyframe frame"),
                                                   _reals(value, np.float32, "keyframe latent" if is_latent else
                                                          "keyframe vertices")))
    if not shapes and not latents:
        raise ValueError("give at least one keyframe")
    out: dict[str, np.ndarray] = {}
    if shapes:
        out["vertex_frames"] = np.array([f for f, _ in shapes], np.int64)
        out["vertices"] = np.stack([v for _, v in shapes])
    if latents:
        out["latent_frames"] = np.array([f for f, _ in latents], np.int64)
        out["latents"] = np.stack([z for _, z in latents])
    return out


_KEYFRAME_NAME = re.compile(r"\b(?:latent_frames|latents|vertex_frames|vertices|keyframes)\[\d+\]")


def _keyframe_names(keyframes: Sequence[KeyframeLike]) -> dict[str, str]:
    """How the request names each keyframe (npz: vertex_frames[j] / vertices[j] and latent_frames[j] / latents[j];
    JSON: keyframes[k], vertex keyframes first, as `_keyframe_arrays` orders them) -> how the caller wrote it
    (keyframes[i].frame, keyframes[i].vertices or .latent, keyframes[i]: i its index in `keyframes`)."""
    shapes: list[int] = []
    latents: list[int] = []
    for i, key in enumerate(keyframes):
        is_latent = "latent" in key if isinstance(key, Mapping) else np.ndim(key[1]) == 1
        (latents if is_latent else shapes).append(i)
    names: dict[str, str] = {}
    for frames, values, what, order, start in (("vertex_frames", "vertices", "vertices", shapes, 0),
                                               ("latent_frames", "latents", "latent", latents, len(shapes))):
        for j, i in enumerate(order):
            names[f"{frames}[{j}]"] = f"keyframes[{i}].frame"
            names[f"{values}[{j}]"] = f"keyframes[{i}].{what}"
            names[f"keyframes[{start + j}]"] = f"keyframes[{i}]"
    return names


def _caller_names(exc: DrapeAPIError, keyframes: Sequence[KeyframeLike]) -> DrapeAPIError:
    """An animate_keyframes error with the keyframes named as the caller wrote them (the service names the
    request's npz members or its reordered JSON list, which the caller never saw)."""
    names = _keyframe_names(keyframes)

    def said(text: str) -> str:
        return _KEYFRAME_NAME.sub(lambda m: names.get(m.group(0), m.group(0)), text)

    return DrapeAPIError(exc.status, exc.type, exc.title, said(exc.detail),
                         field=None if exc.field is None else said(exc.field), retry_after=exc.retry_after)


def _motion_form(motion: MotionFile, fields: dict[str, Any], accept: str | None = None) -> dict:
    """A garment or layers route's httpx arguments for a motion file (BVH or AMASS npz): a multipart form with the
    file as `motion_file` (the server retargets it onto the template's body), its fps and up, and the rest of
    the request as JSON text in `request`; `headers` only when `accept` is given (callers may set their own)."""
    form = _file_form(motion, {"request": json.dumps(fields)})
    return {**form, "headers": {"Accept": accept}} if accept else form


def _keyframes_json(keyframes: Sequence[KeyframeLike]) -> list[dict[str, Any]]:
    """Keyframes as the JSON request's list (vertex keyframes first, as the npz request numbers them)."""
    a = _keyframe_arrays(keyframes)
    return ([{"frame": int(f), "vertices": v.tolist()} for f, v in zip(a.get("vertex_frames", []),
                                                                         a.get("vertices", []), strict=True)]
            + [{"frame": int(f), "latent": z.tolist()} for f, z in zip(a.get("latent_frames", []),
                                                                       a.get("latents", []), strict=True)])


def _encode_npz(vertices: np.ndarray, motion: MotionLike, frame: int) -> dict:
    file = _motion_file(motion)
    if file is not None:
        return _motion_form(file, {"vertices": _finite(_reals(vertices, float, "vertices"), "vertices").tolist(),
                                   "frame": _integer(frame, "frame")}, NPZ)
    return {"content": encode_npz({"vertices": _reals(vertices, np.float32, "vertices"),
                                   "frame": np.array(_integer(frame, "frame")),
                                   **_motion_arrays(motion)}),
            "headers": {"Content-Type": NPZ, "Accept": NPZ}}


def _keyframes_npz(motion: MotionLike, keyframes: Sequence[KeyframeLike], refine: RefineLike,
                   match_keyframes: bool) -> dict:
    file = _motion_file(motion)
    if file is not None:
        return _motion_form(file, {"keyframes": _keyframes_json(keyframes), "refine": _refine_json(refine),
                                   "match_keyframes": bool(match_keyframes)})
    return {"content": encode_npz({**_motion_arrays(motion), **_keyframe_arrays(keyframes), **_refine_members(refine),
                                   "match_keyframes": np.array(bool(match_keyframes))}),
            "headers": {"Content-Type": NPZ}}


def _sample_npz(count: int, seed: int, motion: MotionLike, frame: int) -> dict:
    file = _motion_file(motion)
    if file is not None:
        return _motion_form(file, {"count": _integer(count, "count"), "seed": _integer(seed, "seed"),
                                   "frame": _integer(frame, "frame")}, NPZ)
    return {"content": encode_npz({"count": np.array(_integer(count, "count")), "seed": np.array(_integer(seed, "seed")),
                                   "frame": np.array(_integer(frame, "frame")), **_motion_arrays(motion)}),
            "headers": {"Content-Type": NPZ, "Accept": NPZ}}


def _template(response: httpx.Response) -> GarmentTemplate:
    _raise_for(response)
    z = decode_npz(response.content)
    return GarmentTemplate(str(z["name"]), str(z["body"]), z["vertices"], z["faces"])


def _latent(response: httpx.Response) -> np.ndarray:
    _raise_for(response)
    return decode_npz(response.content)["latent"]


def _samples(response: httpx.Response) -> DesignSamples:
    _raise_for(response)
    z = decode_npz(response.content)
    return DesignSamples(z["latents"], z["vertices"])


def _file_type(format: str) -> str:
    if format not in _FILE_TYPES:
        raise ValueError(f"format must be 'array', 'glb' or 'pc2', not {format!r}")
    return _FILE_TYPES[format]


def _frames_done(reader: FrameReader, status: int) -> np.ndarray:
    if not reader.done or reader.vertices is None:
        raise DrapeAPIError(status, "", "Truncated stream", "the frame stream ended early")
    return reader.vertices


class _Base:
    def __init__(self, base_url: str, api_key: str | None) -> None:
        self.base_url = base_url.rstrip("/")
        self.headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}

    def _prepare(self, outfit: OutfitLike | None, outfit_id: str | None,
                 fit: bool = False) -> tuple[tuple | None, bool]:
        """(arrays, needs_rig): file paths are uploaded through rig first to get an outfit_id."""
        if (outfit is None) == (outfit_id is None):
            raise ValueError("give exactly one of outfit= and outfit_id=")
        if fit and outfit is None:
            raise ValueError("fit=True applies to outfit=; an outfit_id is already rigged")
        if outfit is None:
            return None, False
        arrays = _mesh_arrays(outfit)
        return arrays, arrays is None


class Client(_Base):
    """Blocking client. Keyword-only options; `retries` re-tries failed connections."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, api_key: str | None = None,
                 timeout: float = 120.0, retries: int = 2, transport: httpx.BaseTransport | None = None) -> None:
        super().__init__(base_url, api_key)
        self._http = httpx.Client(base_url=self.base_url, timeout=timeout, headers=self.headers,
                                  transport=transport or httpx.HTTPTransport(retries=retries))

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _get(self, path: str) -> Any:
        r = self._http.get(path)
        _raise_for(r)
        return r.json()

    def health(self) -> Health:
        """The process is alive (GET /healthz): status "ok"."""
        return Health.model_validate(self._get("/healthz"))

    def bodies(self) -> BodyList:
        """The body presets, then the registered user bodies: name, 24-joint skeleton (SMPL order), mesh sizes."""
        return BodyList.model_validate(self._get("/v1/bodies"))

    def motions(self) -> MotionList:
        """The embedded motion clips: name, frames, fps."""
        return MotionList.model_validate(self._get("/v1/motions"))

    def models(self) -> ModelList:
        """Every loaded model: version, files (sha256, inputs/outputs, -1 a dynamic axis), evaluation."""
        return ModelList.model_validate(self._get("/v1/models"))

    def model(self, name: str) -> ModelInfo:
        """One loaded model by name (a name of `models()`: the DeePSD model, intrinsic-<template>)."""
        return ModelInfo.model_validate(self._get(f"/v1/models/{quote(name, safe='')}"))

    @overload
    def rig(self, outfit: OutfitLike, *, body: str = "neutral", influences: int = 4, fit: bool = False,
            format: Literal["array"] = "array") -> RigResult: ...

    @overload
    def rig(self, outfit: OutfitLike, *, body: str = "neutral", influences: int = 4, fit: bool = False,
            format: Literal["glb"]) -> bytes: ...

    def rig(self, outfit: OutfitLike, *, body: str = "neutral", influences: int = 4, fit: bool = False,
            format: RigFormat = "array") -> RigResult | bytes:
        """Rig an outfit: blend weights (at most `influences`, 4 or 8, non-zero per vertex), blend shapes,
        skeleton and its outfit_id (animate it by outfit_id; an outfit given to animate is rigged with its
        `influences`, default 4).
        fit: fit the mesh onto the body first (see `fit`, units and up inferred); RigResult.fit then holds it.
        format="glb": the bytes of a GLB (the outfit skinned to the 24-joint skeleton, its blend shapes as
        morph targets, and the body)."""
        r = self._http.post("/v1/outfits/rig", headers={"Accept": _rig_accept(format)},
                            **_rig_request(outfit, body, influences, fit))
        return _rig_answer(r, format)

    @overload
    def fit(self, outfit: OutfitLike, *, body: str = "neutral", units: str | None = None, up: str | None = None,
            pose: str | np.ndarray = "t", format: Literal["array"] = "array") -> FitResult: ...

    @overload
    def fit(self, outfit: OutfitLike, *, body: str = "neutral", units: str | None = None, up: str | None = None,
            pose: str | np.ndarray = "t", format: Literal["obj"]) -> bytes: ...

    def fit(self, outfit: OutfitLike, *, body: str = "neutral", units: str | None = None, up: str | None = None,
            pose: str | np.ndarray = "t", format: FitFormat = "array") -> FitResult | bytes:
        """Fit a garment made for another body onto `body` at rest: units ("m", "cm", "mm"; None: inferred),
        up axis ("y", "z"; None: inferred), the pose it was made in ("t", "a" or (24, 3) radians).
        format="obj": the fitted garment as OBJ bytes; an OBJ file sent comes back as itself with its vertices
        moved (texture coordinates, materials, objects kept), the report as its first line (a comment)."""
        return _fit_answer(self._http.post("/v1/outfits/fit", headers={"Accept": _fit_accept(format)},
                                           **_fit_request(outfit, body, units, up, pose)), format)

    def register_body(self, body: BodyLike, *, joint_map: Mapping[str, str] | None = None,
                      rest_pose: np.ndarray | None = None) -> BodyRegistered:
        """Register your own body: a skinned GLB / glTF whose 24 joints carry SMPL's names (or `joint_map`'s,
        file name -> SMPL name), or an npz / mapping of vertices (V, 3) m, faces (F, 3), weights (V, 24),
        joints (24, 3) m. rest_pose (24, 3) radians: the pose it is given in, if not a T-pose. Use the
        answer's body_id as `body=` anywhere."""
        return _registered(self._http.post("/v1/bodies", **_body_request(body, joint_map, rest_pose)))

    def body(self, name: str) -> BodyArrays:
        """A body's rest mesh and skeleton (preset or body_id): vertices, faces, weights, joints, parents,
        joint_names."""
        return _body_arrays(name, self._http.get(f"/v1/bodies/{quote(name, safe='')}", headers={"Accept": NPZ}))

    def delete_body(self, name: str) -> None:
        """Take back one registration of a body (each register_body of it counts one); the last forgets it."""
        _raise_for(self._http.delete(f"/v1/bodies/{quote(name, safe='')}"))

    def _animate_body(self, outfit, outfit_id, motion, body, influences, fit, refine) -> dict:  # noqa: ANN001
        """The animate request's httpx arguments (an npz body)."""
        arrays, needs_rig = self._prepare(outfit, outfit_id, fit)
        if needs_rig or (arrays is not None and _motion_file(motion) is not None):
            rig = self.rig(outfit, body=body or "neutral", influences=4 if influences is None else influences,
                           fit=fit)
            outfit_id = rig.outfit_id  # what the rig warned of was raised with its answer
            body, arrays, fit = None, None, False
        return _animate_request(outfit_id, arrays, motion, body, influences, fit, refine)

    @overload
    def animate(self, *, outfit: OutfitLike | None = None, outfit_id: str | None = None, motion: MotionLike,
                body: str | None = None, influences: int | None = None, fit: bool = False,
                refine: RefineLike = False, format: Literal["array"] = "array") -> np.ndarray: ...

    @overload
    def animate(self, *, outfit: OutfitLike | None = None, outfit_id: str | None = None, motion: MotionLike,
                body: str | None = None, influences: int | None = None, fit: bool = False,
                refine: RefineLike = False, format: Literal["glb", "pc2"]) -> bytes: ...

    def animate(self, *, outfit: OutfitLike | None = None, outfit_id: str | None = None, motion: MotionLike,
                body: str | None = None, influences: int | None = None, fit: bool = False,
                refine: RefineLike = False, format: Format = "array") -> np.ndarray | bytes:
        """Posed outfit vertices (T, N, 3) float32 metres; or, with format="glb" / "pc2", the bytes of a
        GLB (the rigged outfit and the body, the motion as its animation) / a PC2 point cache.

        motion: a clip name, poses (T, 24, 3) / (T, 72) axis-angle, a mapping or object with poses, trans, fps,
        or a motion capture file the service imports onto the outfit's body (MotionFile(path, fps=, up=) or a
        Path: a CMU-named BVH or an AMASS-style npz);
        influences: skin influences per vertex, 4 or 8 (None: 4 for an outfit, the rig's for an outfit_id);
        fit: fit the outfit mesh onto the body first, as rig(..., fit=True) does (not with outfit_id);
        refine: the collision refinement post step, True or RefineOptions(eps=, max_iterations=,
        relief_iterations=) (or a mapping of them; fields left out take the service's defaults)."""
        accept = _file_type(format) if format != "array" else None  # before a mesh file is uploaded to be rigged
        req = self._animate_body(outfit, outfit_id, motion, body, influences, fit, refine)
        if accept is not None:
            return self._file("/v1/outfits/animate", accept, **req)
        return self._frames("/v1/outfits/animate", **req)

    def _file(self, path: str, accept: str, **request: Any) -> bytes:
        """POST, the answer's bytes in the format `accept` names."""
        headers = {**request.pop("headers", {}), "Accept": accept}
        r = self._http.post(path, headers=headers, **request)
        _raise_for(r)
        return r.content

    def _frames(self, path: str, **request: Any) -> np.ndarray:
        """POST, reading the frame stream answer into one (T, N, 3) float32 array as it arrives."""
        headers = {"Accept": FRAMES, **request.pop("headers", {})}
        with self._http.stream("POST", path, headers=headers, **request) as r:
            if r.status_code >= 400:
                r.read()
            _raise_for(r)
            reader = FrameReader()
            for data in r.iter_bytes():
                reader.feed(data)
        return _frames_done(reader, r.status_code)

    @overload
    def refine(self, vertices: np.ndarray, faces: np.ndarray, *, motion: MotionLike, body: str = "neutral",
               eps: float | None = None, max_iterations: int | None = None, relief_iterations: int | None = None,
               inner: tuple[np.ndarray, np.ndarray] | None = None, thickness: float | None = None,
               rest_vertices: np.ndarray | None = None,
               format: Literal["array"] = "array") -> np.ndarray: ...

    @overload
    def refine(self, vertices: np.ndarray, faces: np.ndarray, *, motion: MotionLike, body: str = "neutral",
               eps: float | None = None, max_iterations: int | None = None, relief_iterations: int | None = None,
               inner: tuple[np.ndarray, np.ndarray] | None = None, thickness: float | None = None,
               rest_vertices: np.ndarray | None = None,
               format: Literal["glb", "pc2"]) -> bytes: ...

    def refine(self, vertices: np.ndarray, faces: np.ndarray, *, motion: MotionLike, body: str = "neutral",
               eps: float | None = None, max_iterations: int | None = None, relief_iterations: int | None = None,
               inner: tuple[np.ndarray, np.ndarray] | None = None, thickness: float | None = None,
               rest_vertices: np.ndarray | None = None,
               format: Format = "array") -> np.ndarray | bytes:
        """A garment stream (T, N, 3) m with body penetration removed, for the body posed by `motion` (as in
        animate; a motion file must give T frames at its fps) (format="glb" / "pc2": the refined stream as a GLB
        vertex animation / a PC2 point cache, as bytes).

        eps: metres kept from the body; max_iterations: fast-path iterations before the progressive pass;
        relief_iterations: rounds of the stretch relief pass (0: none).
        inner: a garment worn under this one, (vertices (T, Ni, 3) m over the same frames, faces (Fi, 3)): the
        stream is also kept `thickness` (m, default 6 mm) + 1 mm outside it (outer-through-inner removed).
        rest_vertices: the garment at rest (N, 3) m: edges are kept near their rest lengths (pulled under 1.5x,
        or their input length if longer), as animate keeps a rigged outfit's; not with inner.
        None: the service's default (its RefineOptions schema).
        """
        req = _refine_request(vertices, faces, motion, body, eps, max_iterations, relief_iterations, inner, thickness,
                              rest_vertices)
        if format != "array":
            return self._file("/v1/refine", _file_type(format), **req)
        return self._frames("/v1/refine", **req)

    def animate_stream(self, *, outfit: OutfitLike | None = None, outfit_id: str | None = None,
                       motion: MotionLike, body: str | None = None, influences: int | None = None,
                       fit: bool = False, refine: RefineLike = False) -> Iterator[np.ndarray]:
        """Posed frames (N, 3) float32, yielded as they arrive."""
        req = self._animate_body(outfit, outfit_id, motion, body, influences, fit, refine)
        req["headers"]["Accept"] = FRAMES
        with self._http.stream("POST", "/v1/outfits/animate", **req) as r:
            if r.status_code >= 400:
                r.read()
            _raise_for(r)
            dec = FrameDecoder()
            for data in r.iter_bytes():
                yield from dec.feed(data)
            if not dec.done:
                raise DrapeAPIError(r.status_code, "", "Truncated stream", "the frame stream ended early")

    def garments(self) -> GarmentList:
        """The served garment templates (name, vertex count, body, models; intrinsic: fps, window, version,
        latent size)."""
        return GarmentList.model_validate(self._get("/v1/garments"))

    def garment(self, name: str) -> GarmentTemplate:
        """A garment's template mesh in rest pose on its body."""
        return _template(self._http.get(_garment_path(name), headers={"Accept": NPZ}))

    def encode_keyframe(self, name: str, *, vertices: np.ndarray, motion: MotionLike, frame: int) -> np.ndarray:
        """A keyframe shape -> its latent (Z,) float32: vertices (N, 3) m, world space at `frame` (0-based) of
        `motion` (a clip name, a poses array, a mapping with poses, trans, fps, or a MotionFile / Path of a BVH /
        AMASS npz file, imported by the service onto the template's body; so in every garment method)."""
        return _latent(self._http.post(_garment_path(name, "encode"), **_encode_npz(vertices, motion, frame)))

    @overload
    def animate_keyframes(self, name: str, *, motion: MotionLike, keyframes: Sequence[KeyframeLike],
                          refine: RefineLike = False, match_keyframes: bool = True, format: Literal["array"] = "array") -> np.ndarray: ...

    @overload
    def animate_keyframes(self, name: str, *, motion: MotionLike, keyframes: Sequence[KeyframeLike],
                          refine: RefineLike = False, match_keyframes: bool = True, format: Literal["glb", "pc2"]) -> bytes: ...

    def animate_keyframes(self, name: str, *, motion: MotionLike, keyframes: Sequence[KeyframeLike],
                          refine: RefineLike = False, match_keyframes: bool = True, format: Format = "array") -> np.ndarray | bytes:
        """The garment's stream (T, N, 3) float32 m from keyframes: each {"frame": f, "vertices": (N, 3)} (world
        space at frame f) or {"frame": f, "latent": (Z,)}, or a (frame, array) pair; latents are interpolated
        between keyframes and decoded with every frame's motion window; with `match_keyframes` the stream meets
        the shape keyframes exactly (what decoding misses of them is added back, fading away from them);
        `refine` (True or RefineOptions) then pushes the garment out of its body, moving what of a keyframe lies
        inside it. format="glb" / "pc2": the bytes of a GLB vertex animation / a PC2 point cache."""
        req = _keyframes_npz(motion, keyframes, refine, match_keyframes)
        try:
            if format != "array":
                return self._file(_garment_path(name, "animate"), _file_type(format), **req)
            return self._frames(_garment_path(name, "animate"), **req)
        except DrapeAPIError as exc:
            raise _caller_names(exc, keyframes) from None

    def sample_designs(self, name: str, *, count: int, seed: int = 0, motion: MotionLike,
                       frame: int = 0) -> DesignSamples:
        """`count` design candidates (latents from the model's latent statistics, numpy default_rng(seed)) and
        their shapes at `frame` of `motion`, decoded and not refined: at frames of motions unlike the model's
        training ones, part of a shape can lie inside the body (animate_keyframes(..., refine=True) removes it)."""
        return _samples(self._http.post(_garment_path(name, "sample"), **_sample_npz(count, seed, motion, frame)))

    def layers(self) -> LayerList:
        """The served layer combinations (`.layers`): inner, outer, body, thickness [min, max] m, the models that
        pose each layer."""
        return LayerList.model_validate(self._get("/v1/layers"))

    @overload
    def animate_layers(self, *, inner: str, outer: str, motion: MotionLike, thickness: float = 0.006,
                       refine: RefineLike = False, format: Literal["array"] = "array") -> LayerFrames: ...

    @overload
    def animate_layers(self, *, inner: str, outer: str, motion: MotionLike, thickness: float = 0.006,
                       refine: RefineLike = False, format: Literal["glb", "pc2"]) -> bytes: ...

    def animate_layers(self, *, inner: str, outer: str, motion: MotionLike, thickness: float = 0.006,
                       refine: RefineLike = False, format: Format = "array") -> LayerFrames | bytes:
        """Two templates worn together (a combination of `layers()`) along `motion` (a clip name, poses, or the
        MotionFile / Path of a BVH / AMASS npz file, imported by the service onto the combination's body):
        both layers' frames (format="glb" / "pc2": the two as one mesh, inner first, as bytes). thickness: the
        inner garment's, m; refine (True or RefineOptions): both out of the body and the outer kept thickness +
        1 mm outside the inner."""
        req = _layers_request(inner, outer, motion, thickness, refine)
        if format != "array":
            return self._file("/v1/layers/animate", _file_type(format), **req)
        return _layer_frames(self._http.post("/v1/layers/animate", headers={"Accept": NPZ}, **req))


class AsyncClient(_Base):
    """The async twin of Client, on httpx.AsyncClient."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, api_key: str | None = None,
                 timeout: float = 120.0, retries: int = 2,
                 transport: httpx.AsyncBaseTransport | None = None) -> None:
        super().__init__(base_url, api_key)
        self._http = httpx.AsyncClient(base_url=self.base_url, timeout=timeout, headers=self.headers,
                                       transport=transport or httpx.AsyncHTTPTransport(retries=retries))

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self._http.aclose()

    async def _get(self, path: str) -> Any:
        r = await self._http.get(path)
        _raise_for(r)
        return r.json()

    async def health(self) -> Health:
        """See Client.health."""
        return Health.model_validate(await self._get("/healthz"))

    async def bodies(self) -> BodyList:
        """See Client.bodies."""
        return BodyList.model_validate(await self._get("/v1/bodies"))

    async def motions(self) -> MotionList:
        """See Client.motions."""
        return MotionList.model_validate(await self._get("/v1/motions"))

    async def models(self) -> ModelList:
        """See Client.models."""
        return ModelList.model_validate(await self._get("/v1/models"))

    async def model(self, name: str) -> ModelInfo:
        """See Client.model."""
        return ModelInfo.model_validate(await self._get(f"/v1/models/{quote(name, safe='')}"))

    async def garments(self) -> GarmentList:
        """The served garment templates (see Client.garments)."""
        return GarmentList.model_validate(await self._get("/v1/garments"))

    async def garment(self, name: str) -> GarmentTemplate:
        """A garment's template mesh in rest pose on its body."""
        return _template(await self._http.get(_garment_path(name), headers={"Accept": NPZ}))

    async def encode_keyframe(self, name: str, *, vertices: np.ndarray, motion: MotionLike,
                              frame: int) -> np.ndarray:
        """A keyframe shape -> its latent (Z,) float32 (see Client.encode_keyframe)."""
        return _latent(await self._http.post(_garment_path(name, "encode"), **_encode_npz(vertices, motion, frame)))

    @overload
    async def animate_keyframes(self, name: str, *, motion: MotionLike, keyframes: Sequence[KeyframeLike],
                                refine: RefineLike = False, match_keyframes: bool = True,
                                format: Literal["array"] = "array") -> np.ndarray: ...

    @overload
    async def animate_keyframes(self, name: str, *, motion: MotionLike, keyframes: Sequence[KeyframeLike],
                                refine: RefineLike = False, match_keyframes: bool = True,
                                format: Literal["glb", "pc2"]) -> bytes: ...

    async def animate_keyframes(self, name: str, *, motion: MotionLike, keyframes: Sequence[KeyframeLike],
                                refine: RefineLike = False, match_keyframes: bool = True,
                                format: Format = "array") -> np.ndarray | bytes:
        """The garment's stream (T, N, 3) float32 m from keyframes (see Client.animate_keyframes)."""
        req = _keyframes_npz(motion, keyframes, refine, match_keyframes)
        try:
            if format != "array":
                return await self._file(_garment_path(name, "animate"), _file_type(format), **req)
            return await self._frames(_garment_path(name, "animate"), **req)
        except DrapeAPIError as exc:
            raise _caller_names(exc, keyframes) from None

    async def sample_designs(self, name: str, *, count: int, seed: int = 0, motion: MotionLike,
                             frame: int = 0) -> DesignSamples:
        """Design candidates and their shapes at `frame` (see Client.sample_designs)."""
        return _samples(await self._http.post(_garment_path(name, "sample"),
                                              **_sample_npz(count, seed, motion, frame)))

    async def layers(self) -> LayerList:
        """See Client.layers."""
        return LayerList.model_validate(await self._get("/v1/layers"))

    @overload
    async def animate_layers(self, *, inner: str, outer: str, motion: MotionLike, thickness: float = 0.006,
                             refine: RefineLike = False, format: Literal["array"] = "array") -> LayerFrames: ...

    @overload
    async def animate_layers(self, *, inner: str, outer: str, motion: MotionLike, thickness: float = 0.006,
                             refine: RefineLike = False, format: Literal["glb", "pc2"]) -> bytes: ...

    async def animate_layers(self, *, inner: str, outer: str, motion: MotionLike, thickness: float = 0.006,
                             refine: RefineLike = False, format: Format = "array") -> LayerFrames | bytes:
        """See Client.animate_layers."""
        req = _layers_request(inner, outer, motion, thickness, refine)
        if format != "array":
            return await self._file("/v1/layers/animate", _file_type(format), **req)
        return _layer_frames(await self._http.post("/v1/layers/animate", headers={"Accept": NPZ}, **req))

    @overload
    async def rig(self, outfit: OutfitLike, *, body: str = "neutral", influences: int = 4, fit: bool = False,
                  format: Literal["array"] = "array") -> RigResult: ...

    @overload
    async def rig(self, outfit: OutfitLike, *, body: str = "neutral", influences: int = 4, fit: bool = False,
                  format: Literal["glb"]) -> bytes: ...

    async def rig(self, outfit: OutfitLike, *, body: str = "neutral", influences: int = 4, fit: bool = False,
                  format: RigFormat = "array") -> RigResult | bytes:
        """Rig an outfit: RigResult, or the bytes of a GLB with format="glb" (see Client.rig)."""
        r = await self._http.post("/v1/outfits/rig", headers={"Accept": _rig_accept(format)},
                                  **_rig_request(outfit, body, influences, fit))
        return _rig_answer(r, format)

    @overload
    async def fit(self, outfit: OutfitLike, *, body: str = "neutral", units: str | None = None,
                  up: str | None = None, pose: str | np.ndarray = "t",
                  format: Literal["array"] = "array") -> FitResult: ...

    @overload
    async def fit(self, outfit: OutfitLike, *, body: str = "neutral", units: str | None = None,
                  up: str | None = None, pose: str | np.ndarray = "t", format: Literal["obj"]) -> bytes: ...

    async def fit(self, outfit: OutfitLike, *, body: str = "neutral", units: str | None = None,
                  up: str | None = None, pose: str | np.ndarray = "t", format: FitFormat = "array",
                  ) -> FitResult | bytes:
        """See Client.fit."""
        return _fit_answer(await self._http.post("/v1/outfits/fit", headers={"Accept": _fit_accept(format)},
                                                 **_fit_request(outfit, body, units, up, pose)), format)

    async def register_body(self, body: BodyLike, *, joint_map: Mapping[str, str] | None = None,
                            rest_pose: np.ndarray | None = None) -> BodyRegistered:
        """See Client.register_body."""
        return _registered(await self._http.post("/v1/bodies", **_body_request(body, joint_map, rest_pose)))

    async def body(self, name: str) -> BodyArrays:
        """See Client.body."""
        return _body_arrays(name, await self._http.get(f"/v1/bodies/{quote(name, safe='')}",
                                                       headers={"Accept": NPZ}))

    async def delete_body(self, name: str) -> None:
        """See Client.delete_body."""
        _raise_for(await self._http.delete(f"/v1/bodies/{quote(name, safe='')}"))

    async def _animate_body(self, outfit, outfit_id, motion, body, influences, fit, refine) -> dict:  # noqa: ANN001
        arrays, needs_rig = self._prepare(outfit, outfit_id, fit)
        if needs_rig or (arrays is not None and _motion_file(motion) is not None):
            rig = await self.rig(outfit, body=body or "neutral",
                                 influences=4 if influences is None else influences, fit=fit)
            outfit_id, body, arrays, fit = rig.outfit_id, None, None, False
        return _animate_request(outfit_id, arrays, motion, body, influences, fit, refine)

    @overload
    async def animate(self, *, outfit: OutfitLike | None = None, outfit_id: str | None = None,
                      motion: MotionLike, body: str | None = None, influences: int | None = None,
                      fit: bool = False, refine: RefineLike = False, format: Literal["array"] = "array") -> np.ndarray: ...

    @overload
    async def animate(self, *, outfit: OutfitLike | None = None, outfit_id: str | None = None,
                      motion: MotionLike, body: str | None = None, influences: int | None = None,
                      fit: bool = False, refine: RefineLike = False, format: Literal["glb", "pc2"]) -> bytes: ...

    async def animate(self, *, outfit: OutfitLike | None = None, outfit_id: str | None = None,
                      motion: MotionLike, body: str | None = None, influences: int | None = None,
                      fit: bool = False, refine: RefineLike = False, format: Format = "array") -> np.ndarray | bytes:
        """Posed outfit vertices (T, N, 3) float32 metres, or GLB / PC2 bytes (see Client.animate)."""
        accept = _file_type(format) if format != "array" else None  # before a mesh file is uploaded to be rigged
        req = await self._animate_body(outfit, outfit_id, motion, body, influences, fit, refine)
        if accept is not None:
            return await self._file("/v1/outfits/animate", accept, **req)
        return await self._frames("/v1/outfits/animate", **req)

    async def _file(self, path: str, accept: str, **request: Any) -> bytes:
        headers = {**request.pop("headers", {}), "Accept": accept}
        r = await self._http.post(path, headers=headers, **request)
        _raise_for(r)
        return r.content

    async def _frames(self, path: str, **request: Any) -> np.ndarray:
        headers = {"Accept": FRAMES, **request.pop("headers", {})}
        async with self._http.stream("POST", path, headers=headers, **request) as r:
            if r.status_code >= 400:
                await r.aread()
            _raise_for(r)
            reader = FrameReader()
            async for data in r.aiter_bytes():
                reader.feed(data)
        return _frames_done(reader, r.status_code)

    @overload
    async def refine(self, vertices: np.ndarray, faces: np.ndarray, *, motion: MotionLike, body: str = "neutral",
                     eps: float | None = None, max_iterations: int | None = None,
                     relief_iterations: int | None = None,
                     inner: tuple[np.ndarray, np.ndarray] | None = None, thickness: float | None = None,
                     rest_vertices: np.ndarray | None = None,
                     format: Literal["array"] = "array") -> np.ndarray: ...

    @overload
    async def refine(self, vertices: np.ndarray, faces: np.ndarray, *, motion: MotionLike, body: str = "neutral",
                     eps: float | None = None, max_iterations: int | None = None,
                     relief_iterations: int | None = None,
                     inner: tuple[np.ndarray, np.ndarray] | None = None, thickness: float | None = None,
                     rest_vertices: np.ndarray | None = None,
                     format: Literal["glb", "pc2"]) -> bytes: ...

    async def refine(self, vertices: np.ndarray, faces: np.ndarray, *, motion: MotionLike, body: str = "neutral",
                     eps: float | None = None, max_iterations: int | None = None,
                     relief_iterations: int | None = None,
                     inner: tuple[np.ndarray, np.ndarray] | None = None, thickness: float | None = None,
                     rest_vertices: np.ndarray | None = None,
                     format: Format = "array") -> np.ndarray | bytes:
        """A garment stream (T, N, 3) m with body penetration removed, or GLB / PC2 bytes (see Client.refine)."""
        req = _refine_request(vertices, faces, motion, body, eps, max_iterations, relief_iterations, inner,
                              thickness, rest_vertices)
        if format != "array":
            return await self._file("/v1/refine", _file_type(format), **req)
        return await self._frames("/v1/refine", **req)

    async def animate_stream(self, *, outfit: OutfitLike | None = None, outfit_id: str | None = None,
                             motion: MotionLike, body: str | None = None, influences: int | None = None,
                             fit: bool = False, refine: RefineLike = False) -> AsyncIterator[np.ndarray]:
        """Posed frames (N, 3) float32, yielded as they arrive (see Client.animate_stream)."""
        req = await self._animate_body(outfit, outfit_id, motion, body, influences, fit, refine)
        req["headers"]["Accept"] = FRAMES
        async with self._http.stream("POST", "/v1/outfits/animate", **req) as r:
            if r.status_code >= 400:
                await r.aread()
            _raise_for(r)
            dec = FrameDecoder()
            async for data in r.aiter_bytes():
                for frame in dec.feed(data):
                    yield frame
            if not dec.done:
                raise DrapeAPIError(r.status_code, "", "Truncated stream", "the frame stream ended early")
