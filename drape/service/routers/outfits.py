"""POST /v1/outfits/rig, /v1/outfits/animate and /v1/refine: negotiate, read the body within the limits,
take a computing slot, then decode, validate and compute off the event loop; the work is in handlers.

The event loop only moves bytes: everything from JSON parsing on runs in the thread pool, under the
admission control's slot (a 503 + Retry-After when the service is full).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import numpy as np
from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from drape.runtime.engine import RiggedOutfit
from drape.schemas import WARNINGS_HEADER
from drape.schemas.binary import FRAMES, NPZ, encode_npz
from drape.schemas.gltf import GLB, vertex_animation_glb
from drape.schemas.outfits import FIT_HELP, INFLUENCES_HELP, RefineOptions
from drape.schemas.pc2 import PC2
from drape.service import decode, handlers
from drape.service.answers import JSON, FrameSource, stream_frames
from drape.service.errors import LimitExceeded, UnsupportedMediaType
from drape.service.http import admission_of, engine_of, media_type, read_body, settings_of
from drape.service.negotiate import choose
from drape.service.problems import problem_responses
from drape.service.settings import Settings

router = APIRouter(prefix="/v1/outfits", tags=["outfits"])
ERRORS = problem_responses(400, 401, 404, 406, 408, 413, 415, 422, 503)
MESH_FILE = {"type": "string", "format": "binary", "description": "the mesh: an OBJ, PLY, GLB or glTF file (by its "
             "name's extension), metres, +Y up, on the body at rest (unless fitted)"}
FORM_BODY = {"type": "string", "description": "a preset (GET /v1/bodies) or a body_id (POST /v1/bodies); default "
             "neutral"}
FORM_INFLUENCES = {"type": "string", "enum": ["4", "8"], "description": INFLUENCES_HELP + " (default 4)"}


# a 200 done as asked that looks wrong says so (drape.service.notices): the routes that read a motion_file, animate
# with an outfit mesh, a fit answered as OBJ
WARNINGS_ANSWER = {WARNINGS_HEADER: {"required": False, "description": "present when something looks wrong in "
                                     "what was done as asked (a motion file whose skeleton contradicts `up`, feet "
                                     "left off the floor; an outfit mostly inside the body): a JSON array of "
                                     "sentences, each naming its field",
                                     "schema": {"type": "string"}}}
OBJ = "model/obj"  # a fit's answer as a mesh file (IANA registered)



def npz_answer(members: str) -> dict:
    """An npz answer's content entry, naming its members."""
    return {"schema": {"type": "string", "format": "binary", "description": f"npz with {members}"}}


def glb_answer(what: str) -> dict:
    """A GLB answer's content entry (glTF 2.0 binary: metres, +Y up; frame t at t / fps seconds)."""
    return {"schema": {"type": "string", "format": "binary", "description": f"glTF 2.0 binary, metres, +Y up: {what}"}}


SKINNED_GLB = ("the outfit as a mesh skinned to the body's 24 SMPL-named joints (skin weights in sets of 4), its blend "
               "shapes as morph targets psd_<p>, and the body as a second skinned mesh")
VERTEX_GLB = glb_answer("the stream as a vertex animation: frame 0 the base mesh, every later frame a morph target "
                        "with weight 1 at its frame (t / fps seconds)")
RIG_NPZ = npz_answer(
    "outfit_id (text), skinning_weights (N, 24), blend_shapes (P, N, 3) metres, rest_joints (24, 3) metres, parents "
    "(24,), joint_names (24,) text, diagnostics (JSON text: RigDiagnostics); with fit, fit_vertices (N, 3), "
    "fit_faces (F, 3), fit_transform (4, 4), fit_report (JSON text: FitReport); for an OBJ of several objects, "
    "parts (JSON text: [MeshPart])")
FIT_NPZ = npz_answer("vertices (N, 3) metres, faces (F, 3) int32, transform (4, 4) float64, report (JSON text: "
                     "FitReport)")


def _rig_payload(outfit: RiggedOutfit) -> dict[str, np.ndarray]:
    body = handlers.held_body(outfit.body)  # a 404 if DELETEd since the rig
    return {
        "skinning_weights": outfit.rig.weights,
        "blend_shapes": outfit.rig.blend_shapes,
        "rest_joints": body.joints,
        "parents": body.parents,
        "joint_names": np.array(body.joint_names, dtype=np.str_),
    }


@router.post(
    "/rig",
    responses={200: {"description": "the rig (GLB: the outfit skinned with its blend shapes as morph targets, "
                                    "and the body)", "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/RigResponse"}}, NPZ: RIG_NPZ, GLB: glb_answer(SKINNED_GLB)}},
        **ERRORS},
    openapi_extra={"requestBody": {"required": True, "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/RigRequest"}},
        "multipart/form-data": {"schema": {"type": "object", "required": ["mesh"], "properties": {
            "mesh": MESH_FILE, "body": FORM_BODY, "influences": FORM_INFLUENCES,
            "fit": {"type": "string", "enum": ["true", "false"], "description": FIT_HELP + " (default false)"}}}},
        NPZ: {"schema": {"type": "string", "format": "binary",
                         "description": "npz with vertices (N, 3), faces (F, 3), optional body (unicode scalar), "
                                        "optional influences (integer scalar, 4 or 8), optional fit (boolean "
                                        "scalar)"}},
    }}},
)
async def rig_outfit(request: Request) -> Response:
    """Template outfit -> blend weights W (N, 24), blend shapes D (P, N, 3), skeleton, outfit_id."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ, GLB])
    kind = media_type(request)
    if kind not in ("multipart/form-data", NPZ, JSON, ""):
        raise UnsupportedMediaType(f"send {JSON}, multipart/form-data or {NPZ}, not {kind!r}", "Content-Type")
    settings, engine = settings_of(request), engine_of(request)
    data = await read_body(request)
    content_type = request.headers.get("content-type", "")

    def work() -> Response:
        vertices, faces, body_name, influences, fit, parts, uv = decode.rig_arguments(kind, content_type, data,
                                                                                     settings)
        outfit = handlers.rig(engine, settings, vertices, faces, body_name, influences, fit_first=fit, parts=parts,
                              uv_corners=uv,
                              field=mesh_field(kind))
        if answer == GLB:
            return Response(handlers.outfit_glb(engine, outfit), media_type=GLB)
        return _rig_answer(answer, outfit, settings)

    slot = await admission_of(request).enter()
    try:
        return await run_in_threadpool(work)
    finally:
        slot.release()


def mesh_field(kind: str) -> str:
    """Where a rig or fit request of this body type gives its mesh, as errors name it: the form's file `mesh`
    ("mesh.faces: ..."), else the request's own vertices and faces."""
    return "mesh" if kind == "multipart/form-data" else ""


def _rig_answer(answer: str, outfit: RiggedOutfit, settings: Settings) -> Response:
    payload = _rig_payload(outfit)
    if answer == NPZ:
        fitted = {} if outfit.fit is None else _fit_members(outfit.fit, "fit_")
        parts = {} if outfit.parts is None else {"parts": np.array(json.dumps(outfit.parts))}
        return Response(encode_npz({"outfit_id": np.array(outfit.outfit_id), **payload,
                                    "diagnostics": np.array(json.dumps(outfit.diagnostics)), **fitted, **parts}),
                        media_type=NPZ)
    numbers = payload["skinning_weights"].size + payload["blend_shapes"].size
    if numbers > settings.max_json_values:
        raise LimitExceeded(f"the rig has {numbers} numbers, over the limit of {settings.max_json_values} for a "
                            "JSON answer; ask for Accept: application/x-npz", "Accept")
    return JSONResponse({
        "outfit_id": outfit.outfit_id,
        "num_vertices": int(len(outfit.vertices)),
        "skinning_weights": payload["skinning_weights"].tolist(),
        "blend_shapes": payload["blend_shapes"].tolist(),
        "skeleton": {"joint_names": list(payload["joint_names"]), "parents": payload["parents"].tolist(),
                     "rest_joints": payload["rest_joints"].tolist()},
        "diagnostics": outfit.diagnostics,
        **({"fit": outfit.fit} if outfit.fit is not None else {}),
        **({"parts": outfit.parts} if outfit.parts is not None else {}),
    })


def _fit_members(fit: dict, prefix: str = "") -> dict[str, np.ndarray]:
    """A fit answer (FitResponse document) as npz members: vertices, faces, transform, report (JSON text)."""
    return {f"{prefix}vertices": np.asarray(fit["vertices"], np.float32),
            f"{prefix}faces": np.asarray(fit["faces"], np.int32),
            f"{prefix}transform": np.asarray(fit["transform"], np.float64),
            f"{prefix}report": np.array(json.dumps(fit["report"]))}


@router.post(
    "/fit",
    responses={200: {"description": "the garment fitted onto the body at rest", "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/FitResponse"}}, NPZ: FIT_NPZ,
        OBJ: {"schema": {"type": "string", "description": "the fitted garment as an OBJ: an uploaded OBJ with its "
                         "vertices moved and every other line kept (texture coordinates, materials, objects; "
                         "normals turned with the fit, or left out after un-posing), else v/f lines; the report "
                         "as its first line, a comment: '# drape fit report: {...}'"}}},
        "headers": WARNINGS_ANSWER}, **ERRORS},
    openapi_extra={"requestBody": {"required": True, "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/FitRequest"}},
        "multipart/form-data": {"schema": {"type": "object", "required": ["mesh"], "properties": {
            "mesh": {"type": "string", "format": "binary", "description": "the garment: an OBJ, PLY, GLB or glTF "
                     "file (by its name's extension), in any units and up axis, placed anywhere"},
            "body": {**FORM_BODY, "description": "the body to fit the garment onto: " + FORM_BODY["description"]},
            "units": {"type": "string", "enum": ["m", "cm", "mm"], "description": "the mesh's units (default: "
                      "inferred from its size)"},
            "up": {"type": "string", "enum": ["y", "z"], "description": "the mesh's up axis (default: inferred)"},
            "pose": {"type": "string", "description": "the pose the garment was made in: t (T-pose, the default), "
                     "a (arms 45 degrees down), or a JSON (24, 3) array of axis-angle radians"}}}},
        NPZ: {"schema": {"type": "string", "format": "binary",
                         "description": "npz with vertices (N, 3), faces (F, 3), optional body, units, up (unicode "
                                        "scalars), optional pose (unicode scalar t or a, or (24, 3) radians)"}},
    }}},
)
async def fit_outfit(request: Request) -> Response:
    """A garment made for another body (any units, Y- or Z-up, T- or A-pose) -> the garment on the body at rest:
    units converted, up axis turned, placed on the body (rigid), un-posed, pushed out of the body keeping its
    local shape. Answers vertices (N, 3) m, faces, the transform (4, 4) applied before the push-out, and a report
    (units and up as given or inferred, inside shares before and after, the push-out's moves and stretch)."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ, OBJ])
    kind = media_type(request)
    if kind not in ("multipart/form-data", NPZ, JSON, ""):
        raise UnsupportedMediaType(f"send {JSON}, multipart/form-data or {NPZ}, not {kind!r}", "Content-Type")
    settings = settings_of(request)
    data = await read_body(request)
    content_type = request.headers.get("content-type", "")

    def work() -> Response:
        args = decode.fit_arguments(kind, content_type, data, settings)
        source = args.pop("source", None)
        result = handlers.fit(settings, **args, field=mesh_field(kind))
        if answer == OBJ:
            return Response(handlers.fit_obj(result, np.asarray(args["faces"]), source), media_type=OBJ)
        doc = handlers.fit_answer(result, np.asarray(args["faces"]))
        if answer == NPZ:
            return Response(encode_npz(_fit_members(doc)), media_type=NPZ)
        return JSONResponse(doc)

    return await whole_answer(request, work)


def max_posed(answer: str, settings: Settings) -> int | None:
    """frames x vertices one answer may hold in this format (None: the frame stream, unbounded)."""
    return {JSON: settings.max_json_values // 3, NPZ: settings.max_posed_values,
            GLB: settings.max_posed_values}.get(answer)


def fps_field(kind: str) -> str:
    """Where a request of this body type gives its frame rate: the form's fps field, else the motion's."""
    return "fps" if kind == "multipart/form-data" else "motion.fps"


def refine_field_names(kind: str) -> handlers.RefineFieldNames:
    """How a refine request of this body type names its parts (JSON fields, npz members, a form's)."""
    return {NPZ: handlers.REFINE_NPZ_NAMES, "multipart/form-data": handlers.REFINE_FORM_NAMES}.get(
        kind, handlers.REFINE_JSON_NAMES)


def vertex_animation_answer(src: FrameSource, settings: Settings, kind: str, field: str,
                            name: str = "garment") -> Response:
    """A stream's GLB (one morph target a frame), its frame rate and per-frame weights checked before the
    frames are computed (`kind`: the request's body type, for the fps field's name; `field`: the frames' limit)."""
    handlers.check_glb_fps(src.num_frames, src.fps, fps_field(kind))
    handlers.check_glb_frame_targets(src.num_frames, settings.max_posed_values, field)
    check = handlers.whole_answer_budget(settings.request_budget_s, src.num_frames, field)
    chunks: list[np.ndarray] = []
    done = 0
    for chunk in src.chunks():
        chunks.append(chunk)
        done += len(chunk)
        check(done)
    frames = np.concatenate(chunks)
    return Response(vertex_animation_glb(frames, src.faces, src.fps, name=name), media_type=GLB)


STREAM_NPZ = npz_answer("vertices (T, N, 3) float32 metres, faces (F, 3), fps (float32 scalar), outfit_id (text; "
                        "'' but for animate)")
FRAMES_ANSWER = {"schema": {"type": "string", "format": "binary", "description":
                            "the frame stream, little-endian: b'DRPF', u32 version 1, u32 header length H, H bytes of "
                            "JSON header {num_frames, num_vertices, num_faces, fps, dtype '<f4', outfit_id; layers: "
                            "[{name, start, stop}] vertex ranges for POST /v1/layers/animate}; faces "
                            "F x 3 int32; then chunks, each a u32 frame count n and n x N x 3 float32 metres; a "
                            "chunk with n = 0 ends it"}}
PC2_ANSWER = {"schema": {"type": "string", "format": "binary", "description":
                         "PointCache2: a 32-byte header ('POINTCACHE2\\0', int32 version 1, int32 points N, float32 "
                         "start frame 0, float32 sample rate 1, int32 samples T), then T x N x 3 float32 metres; "
                         "the format holds no fps"}}


def frame_answers(glb: dict) -> dict:
    """The 200 and error responses of animate and refine, with the route's GLB."""
    return {200: {"description": "frames (T, N, 3): JSON, npz, the frame stream, PC2 (point cache) or GLB "
                                 "(animate: the rig and its animation; refine: a vertex animation)", "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/AnimateResponse"}}, NPZ: STREAM_NPZ, FRAMES: FRAMES_ANSWER,
        PC2: PC2_ANSWER, GLB: glb}, "headers": WARNINGS_ANSWER}, **ERRORS}



STREAM_FORMATS = [JSON, NPZ, FRAMES, PC2, GLB]


MOTION_FILE = {"type": "string", "format": "binary", "description":
               "a BVH with CMU joint names (retargeted onto the body, the added T-pose frame of raw CMU clips "
               "dropped) or an AMASS-style npz (poses (T, 156) / (T, 52, 3) SMPL-H, (T, 72) / (T, 24, 3) SMPL, "
               "(T, 165) SMPL-X; trans; mocap_framerate), Z-up turned Y-up; resampled to fps (slerp) and put "
               "on the floor, as `drape motions import` does (docs/motion_import.md)"}
FORM_FPS = {"type": "number", "exclusiveMinimum": 0, "maximum": 1000, "default": 30,
            "description": "frame rate the motion file is resampled to"}
FORM_UP = {"type": "string", "enum": ["y", "z"], "description": "the motion file's up axis (default: detected)"}
# the refine options as form fields: RefineOptions' own schema (type, bounds, default, description), so they cannot drift
FORM_OPTIONS = {k: {**v, "description": f"refine option (RefineOptions.{k}): {v['description']}"}
                for k, v in RefineOptions.model_json_schema()["properties"].items()}
# an npz request's motion members (animate, refine, the garment routes)
MOTION_NPZ = ("clip (text) or poses (T, 24, 3) / (T, 72) / (T, 156) radians with optional translation (T, 3) metres "
              "and fps (default 30)")
ANIMATE_FORM = {"schema": {"type": "object", "required": ["motion_file", "outfit_id"], "properties": {
    "motion_file": MOTION_FILE, "outfit_id": {"type": "string", "description": "from POST /v1/outfits/rig"},
    "fps": FORM_FPS, "up": FORM_UP,
    "body": {"type": "string", "description": "the rigged outfit's body, if given (another is a 422)"},
    "influences": {"type": "string", "enum": ["4", "8"], "description": "the rigged outfit's influences, if given "
                   "(others are a 422)"},
    "refine": {"type": "string", "enum": ["true", "false"], "description": "collision refinement post step (default: "
               "false, unless a refine option is given)"}, **FORM_OPTIONS}}}
REFINE_FORM = {"schema": {"type": "object", "required": ["garment", "motion_file"], "properties": {
    "garment": {"type": "string", "format": "binary", "description": "npz with vertices (T, N, 3) metres and faces "
                "(F, 3); optionally a garment under this one: inner_vertices (T, Ni, 3), inner_faces (Fi, 3), "
                "thickness (metres, scalar, default 0.006)"},
    "motion_file": {**MOTION_FILE, "description": MOTION_FILE["description"] + "; it must give T frames at fps"},
    "fps": FORM_FPS, "up": FORM_UP, "body": FORM_BODY, **FORM_OPTIONS}}}


@router.post("/animate", responses=frame_answers(glb_answer(
    SKINNED_GLB + ", with the motion as an animation: per frame the joints' rotations, the root's translation and "
    "the morph weights (pose keys); with refine, one sparse correction morph target per frame")), openapi_extra={"requestBody": {"required": True, "content": {
    JSON: {"schema": {"$ref": "#/components/schemas/AnimateRequest"}},
    NPZ: {"schema": {"type": "string", "format": "binary", "description":
                     f"npz: outfit_id (text) or vertices (N, 3) + faces (F, 3); {MOTION_NPZ}; optional body (text); "
                     "influences (4 or 8); fit (boolean scalar); refine (boolean "
                     "scalar) and/or the refine options as scalars: eps, max_iterations, relief_iterations"}},
    "multipart/form-data": ANIMATE_FORM}}})
async def animate_outfit(request: Request) -> Response:
    """Outfit (or outfit_id) + motion (+ refine) -> posed vertices (T, N, 3): JSON, npz, a frame stream, PC2, or
    GLB (the rigged outfit and the body with the motion as an animation, refinement as per-frame targets).
    A multipart form carries the motion as a file (motion_file: BVH or AMASS npz) with outfit_id."""
    answer = choose(request.headers.get("accept"), STREAM_FORMATS)
    kind = media_type(request)
    if kind not in (JSON, NPZ, "multipart/form-data", ""):
        raise UnsupportedMediaType(f"send {JSON}, {NPZ} or multipart/form-data, not {kind!r}", "Content-Type")
    settings, engine = settings_of(request), engine_of(request)
    data = await read_body(request)
    content_type = request.headers.get("content-type", "")

    if answer == GLB:
        def glb() -> Response:
            req = decode.animate_request(kind, data, settings, engine, content_type)
            p = handlers.plan_animation(engine, settings, req, max_posed(answer, settings))
            handlers.check_glb_fps(p.num_frames, p.fps, fps_field(kind))
            if p.refine is not None:
                handlers.check_glb_frame_targets(p.num_frames, settings.max_posed_values, "motion")
            check = handlers.whole_answer_budget(settings.request_budget_s, p.num_frames, "motion")
            return Response(handlers.outfit_glb(engine, p.outfit, p, progress=check), media_type=GLB)

        return await whole_answer(request, glb)

    def plan() -> FrameSource:
        req = decode.animate_request(kind, data, settings, engine, content_type)
        p = handlers.plan_animation(engine, settings, req, max_posed(answer, settings))

        def chunks() -> Iterator[np.ndarray]:
            return engine.pose_chunks(p.outfit, p.poses, p.translation, settings.stream_chunk_frames,
                                      refine=p.refine, body=p.body)

        return FrameSource(chunks, p.outfit.faces, p.num_frames, len(p.outfit.vertices), p.fps, p.outfit.outfit_id)

    return await stream_answer(request, answer, plan)


async def whole_answer(request: Request, work: Any) -> Response:
    """Take a computing slot and make a whole answer off the event loop (GLB: not streamed)."""
    slot = await admission_of(request).enter()
    try:
        return await run_in_threadpool(work)
    finally:
        slot.release()


async def stream_answer(request: Request, answer: str, plan: Any) -> Response:
    """Take a computing slot, plan off the event loop, and stream the answer (which keeps the slot)."""
    settings = settings_of(request)
    slot = await admission_of(request).enter()
    try:
        source = await run_in_threadpool(plan)
    except BaseException:
        slot.release()
        raise
    return await stream_frames(answer, source, slot, settings.request_budget_s, request.app.state.metrics,
                               settings.send_stall_s)


refine_router = APIRouter(prefix="/v1", tags=["refine"])


@refine_router.post("/refine", responses=frame_answers(VERTEX_GLB), openapi_extra={"requestBody": {"required": True, "content": {
    JSON: {"schema": {"$ref": "#/components/schemas/RefineRequest"}},
    NPZ: {"schema": {"type": "string", "format": "binary", "description":
                     f"npz: vertices (T, N, 3) metres, faces (F, 3), {MOTION_NPZ}; optional body, the options as "
                     "scalars: eps, "
                     "max_iterations, relief_iterations, and a garment under this one: inner_vertices (T, Ni, 3), "
                     "inner_faces (Fi, 3), thickness (metres, scalar), or the garment at rest: rest_vertices (N, 3)"}},
    "multipart/form-data": REFINE_FORM}}})
async def refine_stream(request: Request) -> Response:
    """Garment stream + faces + body motion -> the stream with body penetration removed (same formats as animate;
    GLB: the refined stream as a vertex animation). A multipart form carries the stream as an npz (garment) and
    the motion as a file (motion_file: BVH or AMASS npz). With `inner` (a garment worn under this one, over the
    same frames, and its thickness) the stream is also kept thickness + 1 mm outside the inner layer, itself
    refined against the body first; the answer is this stream only."""
    answer = choose(request.headers.get("accept"), STREAM_FORMATS)
    kind = media_type(request)
    if kind not in (NPZ, JSON, "multipart/form-data", ""):
        raise UnsupportedMediaType(f"send {JSON}, {NPZ} or multipart/form-data, not {kind!r}", "Content-Type")
    settings, engine = settings_of(request), engine_of(request)
    data = await read_body(request)
    content_type = request.headers.get("content-type", "")

    def plan() -> FrameSource:
        vertices, faces, motion, body, options, inner, rest = decode.refine_arguments(kind, data, settings,
                                                                                     content_type)
        p = handlers.plan_refine(settings, vertices, faces, motion, body, options, max_posed(answer, settings), inner,
                                 rest, refine_field_names(kind))

        def chunks() -> Iterator[np.ndarray]:
            return engine.refine_chunks(p.vertices, p.faces, p.body, p.poses, p.translation, p.options,
                                        settings.stream_chunk_frames, inner=p.inner, rest=p.rest)

        return FrameSource(chunks, p.faces, len(p.vertices), p.vertices.shape[1], p.fps, "")

    if answer == GLB:
        def glb() -> Response:
            return vertex_animation_answer(plan(), settings, kind, "vertices")

        return await whole_answer(request, glb)
    return await stream_answer(request, answer, plan)
