"""Request handling that knows nothing of HTTP: validation, rigging, animation plans."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import numpy as np

from drape.assets.body import Body, has_body, list_bodies, load_body
from drape.assets.motion import MAX_POSE_RAD, MAX_TRANSLATION_M, list_clips, load_clip
from drape.geometry.body_scale import body_height
from drape.geometry.fitting import UNITS, FitError, FitResult, fit_garment, infer_units
from drape.geometry.placement import FAR_M, body_distance, placement
from drape.geometry.queries import MeshDistance
from drape.runtime.body_store import PREFIX as USER_BODY_PREFIX
from drape.runtime.engine import Engine, InnerStream, RefineSettings, RiggedOutfit
from drape.runtime.sparse_rig import INFLUENCES
from drape.schemas.gltf import (
    Animation,
    Skeleton,
    SkinnedMesh,
    frame_target_weights,
    key_times_finite,
    skinned_glb,
)
from drape.service.errors import InvalidInput, LimitExceeded, NotFound, quoted
from drape.service.notices import warn
from drape.service.settings import Settings

MAX_WORLD_M = MAX_TRANSLATION_M + 100.0  # |a garment stream's coordinate|: the motion's translation bound plus reach


def _array(value: Any, field: str, dtype: type, ndim: int) -> np.ndarray:
    if isinstance(value, np.ndarray) and value.dtype.kind not in "iuf":
        raise InvalidInput(f"expected real numbers, got dtype {value.dtype}", field)
    if isinstance(value, np.ndarray) and value.dtype.kind == "u" and np.issubdtype(dtype, np.integer) \
            and value.size and value.max() > np.iinfo(dtype).max:  # the cast would wrap it to a negative number
        raise InvalidInput(f"holds {value.max()}, beyond {np.iinfo(dtype).max}", field)
    try:
        arr: np.ndarray = np.asarray(value, dtype=dtype)
    except (ValueError, TypeError, OverflowError) as exc:
        raise InvalidInput(f"not a rectangular numeric array ({exc})", field) from exc
    if arr.ndim != ndim:
        raise InvalidInput(f"expected {ndim} dimensions, got shape {arr.shape}", field)
    return arr


def check_finite_within(a: np.ndarray, bound: float, beyond: str, field: str) -> None:
    """InvalidInput naming `field` if `a` holds NaN or inf, or a value beyond +-bound (`beyond` says so)."""
    if not np.isfinite(a).all():
        raise InvalidInput("contains NaN or infinite values", field)
    if np.abs(a).max() > bound:
        raise InvalidInput(beyond, field)


def check_mesh(vertices: Any, faces: Any, settings: Settings, field: str = "",
               max_abs: float = 100.0, prefix: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """-> (vertices (N, 3) float32, faces (F, 3) int32), or a domain error naming the field; coordinates
    beyond `max_abs` are refused (100: metres; a mesh to fit may be in millimetres). The errors name
    `<field>.vertices` / `<field>.faces`, or `<prefix>vertices` / `<prefix>faces` where a prefix is given (an npz's
    members: "inner_")."""
    pre = prefix if prefix is not None else f"{field}." if field else ""
    if isinstance(faces, np.ndarray) and faces.dtype.kind not in "iu":
        raise InvalidInput(f"must be integer indices, got dtype {faces.dtype}", f"{pre}faces")
    v = _array(vertices, f"{pre}vertices", np.float64, 2)
    f = _array(faces, f"{pre}faces", np.int64, 2)
    if v.shape[1] != 3 or len(v) < 3:
        raise InvalidInput(f"expected (N, 3) with N >= 3, got {v.shape}", f"{pre}vertices")
    if f.shape[1] != 3 or len(f) < 1:
        raise InvalidInput(f"expected (F, 3) with F >= 1, got {f.shape}", f"{pre}faces")
    if len(v) > settings.max_vertices:
        raise LimitExceeded(f"{len(v)} vertices exceed the limit of {settings.max_vertices}", f"{pre}vertices")
    if len(f) > settings.max_faces:
        raise LimitExceeded(f"{len(f)} faces exceed the limit of {settings.max_faces}", f"{pre}faces")
    if not np.isfinite(v).all():
        raise InvalidInput("contains NaN or infinite values", f"{pre}vertices")
    if np.abs(v).max() > max_abs:
        raise InvalidInput(f"coordinates beyond {max_abs:g}: the mesh must be in metres" if max_abs == 100.0 else
                           f"coordinates beyond {max_abs:g} (100 m in millimetres)", f"{pre}vertices")
    if f.min() < 0 or f.max() >= len(v):
        raise InvalidInput(f"indices must lie in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]", f"{pre}faces")
    if np.any((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])):
        raise InvalidInput("a face repeats a vertex index", f"{pre}faces")
    _check_valence(f, len(v), settings.max_vertices, f"{pre}faces")
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    if not np.any(area > 1e-12):
        size = float(np.ptp(v, axis=0).max())
        if 0 < size < 1e-3:  # distinct vertices, but too close for any face to have an area in metres
            raise InvalidInput(f"the mesh is {size:.3g} m across: far too small for a garment in metres (a mesh "
                               "in metres is 0.05-3 m across)", f"{pre}vertices")
        raise InvalidInput("every face has zero area (degenerate mesh)", f"{pre}faces")
    return v.astype(np.float32), f.astype(np.int32)


VALENCE_BUDGET = 100  # sum over vertices of (vertices joined to it)^2, per vertex of the service's limit


def _check_valence(faces: np.ndarray, num_vertices: int, max_vertices: int, field: str) -> None:
    """A 422 when the vertices are joined to too many others: the refinement's sparse solve (fit's push-out,
    refine) fills in about the square of a vertex's valence. Cloth has 6-8 a vertex (a 100k-vertex garment
    ~40 a vertex summed); an 11,000-corner polygon fanned from one vertex took a fit to 4 GB. The budget,
    VALENCE_BUDGET x max_vertices, keeps a 2,000-corner fan (~2 s, ~200 MB)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    e = np.unique(e[:, 0].astype(np.int64) * num_vertices + e[:, 1])
    valence = np.bincount(np.concatenate([e // num_vertices, e % num_vertices]), minlength=num_vertices)
    total = int((valence.astype(np.int64) ** 2).sum())
    if total > VALENCE_BUDGET * max_vertices:
        worst = int(valence.argmax())
        raise InvalidInput(f"vertex {worst} is joined to {int(valence[worst])} others (a polygon of many corners "
                           f"fanned from one vertex?): the squared valences sum to {total}, over the "
                           f"{VALENCE_BUDGET * max_vertices} the refinement's solve is sized for; triangulate such "
                           "polygons evenly", field)


def check_body(name: str | None, field: str = "body") -> str:
    """A preset's name or a registered user body's id (default: neutral); unknown ids are a 404."""
    name = name or "neutral"
    if has_body(name):
        return name
    if name.startswith(USER_BODY_PREFIX):
        raise NotFound(f"unknown body {quoted(name, 60)}: register it first (POST /v1/bodies)", field)
    raise InvalidInput(f"unknown body preset {quoted(name)}; presets: {', '.join(list_bodies())}, or a body_id "
                       "from POST /v1/bodies", field)


def held_body(name: str, field: str = "body") -> Body:
    """A preset or registered body by name, resolved once: a request computes on this Body to its end even if it
    is DELETEd while it streams; a 404 naming `field` if it is unknown or gone already."""
    try:
        return load_body(name)
    except KeyError:
        pass
    hint = ("register it first (POST /v1/bodies)" if name.startswith(USER_BODY_PREFIX)
            else f"presets: {', '.join(list_bodies())}")
    raise NotFound(f"unknown body {quoted(name, 60)}; {hint}", field)


@contextmanager
def computing_on(name: str, field: str = "body") -> Iterator[None]:
    """Work that looks the body `name` up by name as it goes (placement, rig): a KeyError because the body was
    DELETEd meanwhile answers the 404 the request would have had a moment earlier, not a 500."""
    try:
        yield
    except KeyError:
        if has_body(name):
            raise
        raise NotFound(f"body {quoted(name, 60)} was deleted while this request was computed on it; register it "
                       "again (POST /v1/bodies)", field) from None


@dataclass(frozen=True)
class AnimationPlan:
    """What to compute: an outfit and a motion (poses (T, 24, 3) rad, translation (T, 3) m), on the outfit's
    body as resolved when planned (`held_body`)."""

    outfit: RiggedOutfit
    poses: np.ndarray
    translation: np.ndarray
    fps: float
    refine: RefineSettings | None = None
    body: Body | None = None

    @property
    def num_frames(self) -> int:
        return len(self.poses)


def check_motion(motion: dict, settings: Settings) -> tuple[np.ndarray, np.ndarray, float]:
    """motion: {"clip": name} or {"poses": ..., "translation": ..., "fps": ...} -> (poses, translation, fps)."""
    clip, poses = motion.get("clip"), motion.get("poses")
    if (clip is None) == (poses is None):
        raise InvalidInput("give exactly one of 'clip' and 'poses'", "motion")
    if clip is not None:
        if clip not in list_clips():
            raise NotFound(f"unknown clip {quoted(clip)}; see GET /v1/motions", "motion.clip")
        m = load_clip(clip)
        p, tr, fps = m.poses.astype(np.float64), m.trans.astype(np.float64), m.fps
    else:
        try:
            p = np.asarray(poses, dtype=np.float64)
        except (ValueError, TypeError, OverflowError) as exc:
            raise InvalidInput(f"not a rectangular numeric array ({exc})", "motion.poses") from exc
        if p.ndim == 3 and p.shape[1:] == (24, 3):
            pass
        elif p.ndim == 2 and p.shape[1] in (72, 156):
            p = p[:, :72].reshape(-1, 24, 3)
        else:
            raise InvalidInput(f"expected (T, 24, 3), (T, 72) or (T, 156), got {p.shape}", "motion.poses")
        fps = float(motion.get("fps", 30.0))
        tr_in = motion.get("translation")
        tr = np.zeros((len(p), 3)) if tr_in is None else _array(tr_in, "motion.translation", np.float64, 2)
        if tr.shape != (len(p), 3):
            raise InvalidInput(f"expected ({len(p)}, 3) to match the poses, got {tr.shape}", "motion.translation")
    if len(p) < 1:
        raise InvalidInput("needs at least one frame", "motion.poses")
    if len(p) > settings.max_frames:
        raise LimitExceeded(f"{len(p)} frames exceed the limit of {settings.max_frames}", "motion.poses")
    if not (np.isfinite(p).all() and np.isfinite(tr).all()):
        raise InvalidInput("contains NaN or infinite values", "motion")
    if np.abs(tr).max(initial=0.0) > MAX_TRANSLATION_M:
        raise InvalidInput("translation beyond 10 km", "motion.translation")
    if np.abs(p).max(initial=0.0) > MAX_POSE_RAD:
        raise InvalidInput(f"axis-angle values beyond {MAX_POSE_RAD:g} radians", "motion.poses")
    if not (0 < fps <= 1000):
        raise InvalidInput(f"must be in (0, 1000], got {fps}", "motion.fps")
    return p, tr, fps


def check_influences(value: Any, field: str = "influences") -> int:
    """None -> 4; 4 or 8 (a number, or its text from a form field) -> itself; else a domain error."""
    if value is None:
        return 4
    if isinstance(value, str) and value.strip() in ("4", "8"):
        return int(value)
    if isinstance(value, int | float) and not isinstance(value, bool) and value in INFLUENCES:
        return int(value)
    raise InvalidInput(f"must be 4 or 8 (skin weights per vertex), got {quoted(str(value))}", field)


@lru_cache(maxsize=16)
def _rest_distance(body: str) -> MeshDistance:
    """The body's distance queries at rest, built once per body (its KD-trees), for every rig's placement."""
    b = load_body(body)
    return body_distance(b.vertices, b.faces)


def check_on_body(vertices: np.ndarray, body: str, field: str = "vertices") -> dict:
    """The mesh's placement on the body at rest (drape.geometry.placement); a 422 if no vertex is within
    FAR_M of the body surface (the garment is not on this body)."""
    b = load_body(body)
    report = placement(vertices, b.vertices, b.faces, _rest_distance(body))
    if report["distance_mm"]["min"] > FAR_M * 1e3:
        lo, hi = report["bbox"]["garment"]
        raise InvalidInput(f"no vertex is within {FAR_M * 100:.0f} cm of the {body} body at rest (the nearest is "
                           f"{report['distance_mm']['min'] / 1e3:.2f} m away; the mesh spans "
                           f"{np.round(lo, 2).tolist()} to {np.round(hi, 2).tolist()} m): place it on the body, "
                           "in metres, Y-up", field)
    return report


def _choice(value: Any, allowed: tuple[str, ...], field: str) -> str | None:
    if value is None:
        return None
    if not isinstance(value, str) or value not in allowed:
        raise InvalidInput(f"must be one of {', '.join(allowed)} (or left out to infer it), got "
                           f"{quoted(str(value), 40)}", field)
    return value


def _fit_pose(value: Any) -> str | np.ndarray:
    if value is None or (isinstance(value, str) and value in ("t", "a")):
        return value or "t"
    if isinstance(value, str):
        raise InvalidInput(f"must be 't', 'a' or (24, 3) axis-angle radians, got {quoted(value, 40)}", "pose")
    p = _array(value, "pose", np.float64, 2)
    if p.shape != (24, 3):
        raise InvalidInput(f"expected (24, 3) axis-angle radians, got {p.shape}", "pose")
    if not np.isfinite(p).all() or np.abs(p).max() > 2 * np.pi:
        raise InvalidInput("must be finite axis-angle radians within 2 pi", "pose")
    return p


def fit(settings: Settings, vertices: Any, faces: Any, body: str | None, units: Any = None, up: Any = None,
        pose: Any = None, field: str = "") -> FitResult:
    """Fit a garment made for another body onto a body preset at rest (drape.geometry.fitting); a 422 when
    it sits nowhere on the body. field: the mesh's field prefix in errors (e.g. "outfit")."""
    pre = f"{field}." if field else ""
    v, f = check_mesh(vertices, faces, settings, field, max_abs=1e5)
    body_name = check_body(body)
    units_ = _choice(units, tuple(UNITS), "units")
    up_ = _choice(up, ("y", "z"), "up")
    pose_ = _fit_pose(pose)
    scale = UNITS[units_ or infer_units(v)]
    if np.abs(v).max() * scale > 100.0:
        raise InvalidInput(f"coordinates beyond 100 m in {units_ or infer_units(v)}", f"{pre}vertices")
    try:
        result = fit_garment(v, f, held_body(body_name), units=units_, up=up_, pose=pose_)
    except FitError as exc:
        raise InvalidInput(str(exc), "pose" if exc.argument == "pose" else f"{pre}{exc.argument}") from None
    for sentence in result.report.get("warnings", []):  # in the answer's body too; the header in every format
        warn(f"{field or 'vertices'}: {sentence}")
    return result


def body_scale_warnings(engine: Engine, body: str) -> list[str]:
    """A sentence when the rig model reads this body scaled into the heights it was trained on
    (drape.geometry.body_scale), else none."""
    b = load_body(body)
    scale = engine.model.body_scale(b)
    if scale is None:
        return []
    lo, hi = engine.model.trained_heights or (0.0, 0.0)
    height = body_height(b.vertices)
    return [f"the {body} body is {height:.3f} m tall, outside the {lo:.3f}-{hi:.3f} m of the bodies the rig model "
            f"was trained on: it reads the garment scaled to {height * scale.scale[1]:.3f} m; expect more of it inside "
            "the body when posed (refine: true removes it)"]


def placement_diagnostics(engine: Engine, vertices: np.ndarray, body: str, field: str, said_as: str) -> dict:
    """A rig's `diagnostics`: where the mesh sits on the body at rest (`check_on_body`, its 422 naming `field`)
    with the body-scale warning added; each warning also said in the answer's Drape-Warnings as `said_as: ...`."""
    diagnostics = check_on_body(vertices, body, field)
    diagnostics["warnings"] += body_scale_warnings(engine, body)
    for sentence in diagnostics["warnings"]:
        warn(f"{said_as}: {sentence}")
    return diagnostics


def fit_obj(result: FitResult, faces: np.ndarray, source: tuple[str, bytes] | None) -> bytes:
    """The fitted garment as an OBJ: an uploaded OBJ (source: (file name, bytes)) with its vertices moved and every
    other line kept (UVs, materials, objects; normals turned with the fit, or left out after an un-posing:
    drape.geometry.mesh_io.rewrite_obj), else plain v/f lines; the report as a first comment line, its warnings
    also said (the Drape-Warnings header)."""
    from drape.geometry.mesh_io import obj_lines, rewrite_obj

    head = f"# drape fit report: {json.dumps(result.report)}\n".encode()
    if source is not None and source[0].lower().endswith(".obj"):
        turn = result.transform[:3, :3] if result.report.get("pose") == "t" else None
        try:
            return head + rewrite_obj(source[1], result.vertices, turn)[0]
        except ValueError as exc:  # its v lines are not the vertices read: plain lines, below, and said
            warn(f"mesh: the OBJ could not be written back line for line ({exc}): answered as plain v and f lines, "
                 "without its texture coordinates, normals and materials")
    return head + ("\n".join(obj_lines(result.vertices, faces)) + "\n").encode()


def fit_answer(result: FitResult, faces: np.ndarray) -> dict:
    """A FitResult as the FitResponse document."""
    return {"vertices": result.vertices.tolist(), "faces": np.asarray(faces).tolist(),
            "transform": result.transform.tolist(), "report": result.report}


def rig(engine: Engine, settings: Settings, vertices: Any, faces: Any, body: str | None,
        influences: Any = None, fit_first: bool = False, parts: list[dict] | None = None,
        field: str = "", uv_corners: np.ndarray | None = None) -> RiggedOutfit:
    """Rig an outfit (fitted onto the body first with fit_first); the answer carries its placement
    diagnostics, with fit_first the fit (RiggedOutfit.fit: vertices, faces, transform, report), and the
    mesh file's named parts (vertex ranges) when it has several. field: the mesh's field prefix in errors
    (e.g. "mesh" for an uploaded file: "mesh.faces"). uv_corners (F, 3, 2): the mesh file's texture
    coordinates, kept with the rig for its GLB (and the GLBs animate makes of its outfit_id)."""
    fitted = fit(settings, vertices, faces, body, field=field) if fit_first else None
    v, f = check_mesh(vertices if fitted is None else fitted.vertices, faces, settings, field)
    body_name = check_body(body)
    with computing_on(body_name):
        diagnostics = placement_diagnostics(engine, v, body_name, f"{field}.vertices" if field else "vertices",
                                            field or "vertices")
        uv = None  # -0.0 read as 0.0: the same UVs, one outfit_id
        if uv_corners is not None and np.shape(uv_corners) == (len(f), 3, 2):
            uv = np.asarray(uv_corners, np.float32) + np.float32(0.0)
        outfit = engine.rig(v, f, body_name, check_influences(influences), uv_corners=uv)
    return replace(outfit, diagnostics=diagnostics, fit=None if fitted is None else fit_answer(fitted, f),
                   parts=parts)


def check_refine(value: Any) -> RefineSettings | None:
    """refine: false/None -> None, true -> defaults, {eps, max_iterations, relief_iterations} -> those
    (validated upstream)."""
    if not value:
        return None
    if value is True:
        return RefineSettings()
    return RefineSettings(eps=float(value["eps"]), max_iterations=int(value["max_iterations"]),
                          relief_iterations=int(value["relief_iterations"]))


def check_answer_size(frames: int, vertices: int, max_posed: int | None, field: str) -> None:
    """frames x vertices against the limit of the answer's format (None: the frame stream, no limit)."""
    if max_posed is not None and frames * vertices > max_posed:
        raise LimitExceeded(
            f"{frames} frames x {vertices} vertices exceed the limit of {max_posed} for one answer in this format; "
            "ask for application/x-npz or the frame stream (Accept: application/x-drape-frames)", field)


def check_glb_fps(frames: int, fps: float, field: str) -> None:
    """A GLB answer's frame rate: its animation keys frame t at t / fps seconds in float32, so every key time must
    be finite there (a frame rate that rounds to 0 in float32, or puts the last frame beyond float32's range, is a
    domain error naming `field`)."""
    if not key_times_finite(frames, fps):
        raise InvalidInput(f"{fps:g} fps is too low for a glTF animation: the key times of {frames} frames (frame / "
                           "fps seconds, float32) would not be finite; ask for a higher fps or another format "
                           "(npz, the frame stream, PC2)", field)


def check_glb_frame_targets(frames: int, max_values: int, field: str) -> None:
    """A GLB answer that plays one morph target per frame (a vertex animation; animate with refinement's
    corrections) animates their weights with frames x (frames - 1) values, quadratic in the frames: bounded
    like the other answers' values (`max_values`, DRAPE_MAX_POSED_VALUES), a 413 naming `field`."""
    if frame_target_weights(frames) > max_values:
        raise LimitExceeded(
            f"{frames} frames need {frames} x {frames - 1} morph-target weights in a GLB (one target a frame), over "
            f"the limit of {max_values}; ask for fewer frames or another format (npz, the frame stream, PC2)", field)


def whole_answer_budget(budget_s: float, frames: int, field: str) -> Callable[[int], None]:
    """For an answer made whole before it is sent (GLB): a check to call with the frames done so far, which
    raises a 413 naming `field` once `budget_s` (DRAPE_REQUEST_BUDGET_S) has passed since this call. A streamed
    answer is cut at the budget and keeps what was sent; a whole one has sent nothing, so it says so instead of
    holding its computing slot past the budget."""
    deadline = time.monotonic() + budget_s

    def check(done: int) -> None:
        if done < frames and time.monotonic() > deadline:
            raise LimitExceeded(
                f"the request's time budget of {budget_s:g} s ran out after {done} of {frames} frames; ask for "
                "fewer frames or a streamed format (npz, JSON, the frame stream, PC2), which sends what is done",
                field)

    return check


def unknown_outfit(engine: Engine, outfit_id: str) -> NotFound:
    """The 404 for an outfit_id `engine.lookup` does not find: expired from the cache, or rigged on a user body
    deleted since (then it says so: rigging again on that body fails too)."""
    body = engine.missing_body_of(outfit_id)
    if body is not None:
        return NotFound(f"outfit_id {quoted(outfit_id)} was rigged on user body {body!r}, which was deleted: "
                        "register the body again (the same file gives the same id) or rig on another body",
                        "outfit_id")
    return NotFound(f"unknown outfit_id {quoted(outfit_id)}: rig the outfit again (ids expire from the cache)",
                    "outfit_id")


def plan_animation(engine: Engine, settings: Settings, request: dict, max_posed: int | None) -> AnimationPlan:
    """Validate an animate request (a dict shaped like AnimateRequest) into a plan; `max_posed` bounds
    frames x vertices for the answer's format (None: no bound)."""
    outfit_in, outfit_id = request.get("outfit"), request.get("outfit_id")
    if (outfit_in is None) == (outfit_id is None):
        raise InvalidInput("give exactly one of 'outfit' and 'outfit_id'", "outfit")
    if outfit_id is not None:
        if request.get("fit"):
            raise InvalidInput("fit applies to an outfit mesh; an outfit_id is already rigged", "fit")
        outfit = engine.lookup(outfit_id)
        if outfit is None:
            raise unknown_outfit(engine, outfit_id)
        if request.get("body") not in (None, outfit.body):
            raise InvalidInput(f"outfit {outfit_id} was rigged on body {outfit.body!r}", "body")
        if request.get("influences") is not None and check_influences(request["influences"]) != outfit.influences:
            raise InvalidInput(f"outfit {outfit_id} was rigged with {outfit.influences} influences per vertex",
                               "influences")
        poses, trans, fps = check_motion(request["motion"], settings)
        check_answer_size(len(poses), len(outfit.vertices), max_posed, "motion")
    else:  # every cheap check before the rig
        assert outfit_in is not None
        if request.get("fit"):
            fitted = fit(settings, outfit_in["vertices"], outfit_in["faces"], request.get("body"), field="outfit")
            outfit_in = {**outfit_in, "vertices": fitted.vertices}  # its warnings said by fit
        v, f = check_mesh(outfit_in["vertices"], outfit_in["faces"], settings, "outfit")
        body = check_body(request.get("body"))
        influences = check_influences(request.get("influences"))
        poses, trans, fps = check_motion(request["motion"], settings)
        check_answer_size(len(poses), len(v), max_posed, "motion")
        with computing_on(body):
            placement_diagnostics(engine, v, body, "outfit.vertices", "outfit")  # what a rig answer would say
            outfit = engine.rig(v, f, body, influences)
    return AnimationPlan(outfit, poses, trans, fps, check_refine(request.get("refine")), held_body(outfit.body))


@dataclass(frozen=True)
class RefinePlan:
    """A garment stream (T, N, 3) float32 + faces to refine against `body` (resolved when planned: `held_body`)
    posed by (poses, translation)."""

    vertices: np.ndarray
    faces: np.ndarray
    body: Body
    poses: np.ndarray
    translation: np.ndarray
    fps: float
    options: RefineSettings
    inner: InnerStream | None = None  # a garment under this one: the stream is pushed out of it too
    rest: np.ndarray | None = None  # (N, 3) float64 m, the garment at rest: edges kept near their rest lengths


@dataclass(frozen=True)
class RefineFieldNames:
    """How a refine request names its parts, for its errors: the stream's (`stream` + vertices, faces,
    rest_vertices), the inner layer's (`inner` + vertices, faces; `thickness`) and the motion's."""

    stream: str = ""
    inner: str = "inner."
    thickness: str = "inner.thickness"
    motion: str = "motion"


REFINE_JSON_NAMES = RefineFieldNames()  # {"vertices", ..., "inner": {"vertices", "faces", "thickness"}, "motion"}
REFINE_NPZ_NAMES = RefineFieldNames(inner="inner_", thickness="thickness")  # members inner_vertices, ..., thickness
REFINE_FORM_NAMES = RefineFieldNames(stream="garment.", inner="garment.inner_", thickness="garment.thickness",
                                     motion="motion_file")  # the garment npz's members; the motion_file imported


def check_inner(inner: dict, frames: int, settings: Settings,
                names: RefineFieldNames = REFINE_JSON_NAMES) -> InnerStream:
    """An inner layer {"vertices" (T, Ni, 3), "faces" (Fi, 3), "thickness" m} over `frames` frames; the errors
    name the request's own fields (`names`)."""
    pre = names.inner
    v = _array(inner.get("vertices"), f"{pre}vertices", np.float64, 3)
    if v.shape[0] != frames or v.shape[1] < 3 or v.shape[2] != 3:
        raise InvalidInput(f"expected ({frames}, Ni, 3) with Ni >= 3 (the stream's frames), got {v.shape}",
                           f"{pre}vertices")
    check_finite_within(v, MAX_WORLD_M, f"coordinates beyond {MAX_WORLD_M:g} m: the stream must be in metres",
                        f"{pre}vertices")
    _, f = check_mesh(v[0], inner.get("faces"), settings, prefix=pre)
    t = inner.get("thickness")
    if isinstance(t, bool) or not isinstance(t, int | float) or not 0 < t <= 0.05:
        raise InvalidInput(f"expected a thickness in metres in (0, 0.05], got {str(t)[:40]}", names.thickness)
    return InnerStream(v.astype(np.float32), f, float(t))


def plan_refine(settings: Settings, vertices: Any, faces: Any, motion: dict, body: str | None,
                options: dict | None, max_posed: int | None, inner: dict | None = None,
                rest_vertices: Any = None, names: RefineFieldNames = REFINE_JSON_NAMES) -> RefinePlan:
    """Validate a refine request: the stream's shape, the faces, the motion (same frame count), the inner
    layer if any (the same frames), the rest shape if any (the stream's vertex count; not with an inner layer).
    The errors name the request's own fields (`names`: a JSON body's, an npz's members, a form's)."""
    pre = names.stream
    v = _array(vertices, f"{pre}vertices", np.float64, 3)
    if v.shape[0] < 1 or v.shape[2] != 3 or v.shape[1] < 3:
        raise InvalidInput(f"expected (T, N, 3) with T >= 1 and N >= 3, got {v.shape}", f"{pre}vertices")
    if v.shape[0] > settings.max_frames:
        raise LimitExceeded(f"{v.shape[0]} frames exceed the limit of {settings.max_frames}", f"{pre}vertices")
    _, f = check_mesh(v[0], faces, settings, prefix=pre)
    # frame 0 is within 100 m (check_mesh); later frames may travel
    check_finite_within(v, MAX_WORLD_M, f"coordinates beyond {MAX_WORLD_M:g} m: the stream must be in metres",
                        f"{pre}vertices")
    poses, trans, fps = check_motion(motion, settings)
    if len(poses) != len(v):
        raise InvalidInput(f"the motion has {len(poses)} frames (at {fps:g} fps), the stream {len(v)}", names.motion)
    check_answer_size(v.shape[0], v.shape[1], max_posed, f"{pre}vertices")
    opts = check_refine(options or True)
    assert opts is not None
    layer = None
    if inner is not None:
        layer = check_inner(inner, len(v), settings, names)
        # the inner layer is refined too: its frames count against the same bound as the answer's
        check_answer_size(v.shape[0], v.shape[1] + layer.vertices.shape[1], max_posed, f"{names.inner}vertices")
    rest = None
    if rest_vertices is not None:
        if inner is not None:
            raise InvalidInput("not with inner: the refinement between layers keeps no rest lengths", f"{pre}rest_vertices")
        rest = _array(rest_vertices, f"{pre}rest_vertices", np.float64, 2)
        if rest.shape != (v.shape[1], 3):
            raise InvalidInput(f"expected ({v.shape[1]}, 3), the stream's vertices, got {rest.shape}", f"{pre}rest_vertices")
        check_finite_within(rest, 100.0, "coordinates beyond 100 m: the rest shape must be in metres",
                            f"{pre}rest_vertices")
    return RefinePlan(v.astype(np.float32), f, held_body(check_body(body)), poses, trans, fps, opts, layer, rest)


def outfit_glb(engine: Engine, outfit: RiggedOutfit, plan: AnimationPlan | None = None,
               progress: Callable[[int], None] | None = None) -> bytes:
    """The rig as a GLB: the outfit skinned to the body's skeleton with its blend shapes as morph targets
    (`psd_<p>`), the body skinned beside it; with a plan, its motion as an animation whose morph weights
    are the pose keys (and, with refinement, one sparse correction target per frame; `progress` is called
    with the frames refined so far, e.g. `whole_answer_budget`'s check)."""
    body = plan.body if plan is not None and plan.body is not None else held_body(outfit.body)
    rig = outfit.rig
    meshes = [SkinnedMesh("outfit", outfit.vertices, outfit.faces, rig.weights, rig.blend_shapes,
                          tuple(f"psd_{p}" for p in range(len(rig.blend_shapes))), outfit.uv_corners),
              SkinnedMesh("body", body.vertices, body.faces, body.weights)]
    animation = None
    if plan is not None:
        keys, corrections = engine.export_animation(outfit, plan.poses, plan.translation, plan.refine, body=body,
                                                    progress=progress)
        animation = Animation(plan.poses, plan.translation, plan.fps, keys, corrections)
    extras = {"drape": {"outfit_id": outfit.outfit_id, "influences": outfit.influences,
                        **({"diagnostics": outfit.diagnostics} if outfit.diagnostics else {})}}
    return skinned_glb(Skeleton(body.joint_names, body.parents, body.joints), meshes, animation, extras)

