"""POST /v1/outfits/rig and /v1/outfits/animate: parse, negotiate, stream; the work is in handlers."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from functools import partial
from typing import Any

import numpy as np
from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, StreamingResponse
from pydantic import BaseModel, ValidationError

from drape.assets.body import load_body
from drape.runtime.engine import RiggedOutfit
from drape.schemas.binary import FRAMES, NPZ, decode_npz, encode_npz, stream_chunk, stream_header
from drape.schemas.outfits import AnimateRequest, RefineOptions, RefineRequest, RigRequest
from drape.service import handlers
from drape.service.errors import InvalidInput, MalformedInput, UnsupportedMediaType
from drape.service.http import engine_of, media_type, parse_json, read_body, settings_of
from drape.service.negotiate import choose
from drape.service.problems import problem_responses

router = APIRouter(prefix="/v1/outfits", tags=["outfits"])
JSON = "application/json"
BINARY = {"schema": {"type": "string", "format": "binary"}}
ERRORS = problem_responses(400, 401, 404, 406, 413, 415, 422)


def _validation_detail(exc: ValidationError) -> str:
    return "; ".join(f"{'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in exc.errors()[:5])


def _rig_payload(outfit: RiggedOutfit) -> dict[str, np.ndarray]:
    body = load_body(outfit.body)
    return {
        "skinning_weights": outfit.rig.weights,
        "blend_shapes": outfit.rig.blend_shapes,
        "rest_joints": body.joints,
        "parents": body.parents,
        "joint_names": np.array(body.joint_names, dtype=np.str_),
    }


@router.post(
    "/rig",
    responses={200: {"description": "the rig", "content": {JSON: {"schema": {"$ref": "#/components/schemas/RigResponse"}},
                                                          NPZ: BINARY}}, **ERRORS},
    openapi_extra={"requestBody": {"required": True, "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/RigRequest"}},
        "multipart/form-data": {"schema": {"type": "object", "required": ["mesh"], "properties": {
            "mesh": {"type": "string", "format": "binary", "description": "OBJ, PLY, GLB or glTF file"},
            "body": {"type": "string"}}}},
        NPZ: {"schema": {"type": "string", "format": "binary",
                         "description": "npz with vertices (N, 3), faces (F, 3), optional body (unicode scalar)"}},
    }}},
)
async def rig_outfit(request: Request) -> Response:
    """Template outfit -> blend weights W (N, 24), blend shapes D (P, N, 3), skeleton, outfit_id."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ])
    kind = media_type(request)
    settings, engine = settings_of(request), engine_of(request)
    vertices: Any
    faces: Any
    if kind == "multipart/form-data":
        form = await request.form(max_part_size=settings.max_body_bytes)
        upload = form.get("mesh")
        if upload is None or isinstance(upload, str):
            raise InvalidInput("a mesh file is required", "mesh")
        data = await upload.read()
        body = form.get("body")
        vertices, faces = handlers.mesh_from_file(data, upload.filename or "")
        body_name = body if isinstance(body, str) else None
    elif kind == NPZ:
        try:
            arrays = decode_npz(await read_body(request))
        except ValueError as exc:
            raise MalformedInput(str(exc), "body") from exc
        if "vertices" not in arrays or "faces" not in arrays:
            raise InvalidInput("the archive needs arrays 'vertices' and 'faces'", "body")
        vertices, faces = arrays["vertices"], arrays["faces"]
        body_name = str(arrays["body"]) if "body" in arrays else None
    elif kind in (JSON, ""):
        try:
            req = RigRequest.model_validate(parse_json(await read_body(request)))
        except ValidationError as exc:
            raise InvalidInput(_validation_detail(exc)) from exc
        vertices, faces, body_name = req.vertices, req.faces, req.body
    else:
        raise UnsupportedMediaType(f"send {JSON}, multipart/form-data or {NPZ}, not {kind!r}", "Content-Type")
    outfit = await run_in_threadpool(handlers.rig, engine, settings, vertices, faces, body_name)
    payload = _rig_payload(outfit)
    if answer == NPZ:
        return Response(encode_npz({"outfit_id": np.array(outfit.outfit_id), **payload}), media_type=NPZ)
    return JSONResponse({
        "outfit_id": outfit.outfit_id,
        "num_vertices": int(len(outfit.vertices)),
        "skinning_weights": payload["skinning_weights"].tolist(),
        "blend_shapes": payload["blend_shapes"].tolist(),
        "skeleton": {"joint_names": list(payload["joint_names"]), "parents": payload["parents"].tolist(),
                     "rest_joints": payload["rest_joints"].tolist()},
    })


def _frames_answer(answer: str, chunks: Callable[[], Iterator[np.ndarray]], faces: np.ndarray, n: int,
                   num_frames: int, fps: float, outfit_id: str, metrics: Any) -> Response:
    """Posed or refined frames as JSON, npz or the frame stream; every format from the same chunks."""
    if answer == FRAMES:
        def frames() -> Iterator[bytes]:
            yield stream_header(num_frames, faces, n, fps, outfit_id)
            for chunk in chunks():
                metrics.served(len(chunk), n)
                yield stream_chunk(chunk)
            yield stream_chunk(np.zeros((0, n, 3), np.float32))

        return StreamingResponse(frames(), media_type=FRAMES)
    verts = np.concatenate(list(chunks()))
    metrics.served(len(verts), n)
    if answer == NPZ:
        return Response(encode_npz({"vertices": verts, "faces": faces, "fps": np.array(fps, np.float32),
                                    "outfit_id": np.array(outfit_id)}), media_type=NPZ)
    return JSONResponse({"outfit_id": outfit_id, "fps": fps, "vertices": verts.tolist(), "faces": faces.tolist()})


def _parse(model: type[BaseModel], data: bytes) -> BaseModel:
    try:
        return model.model_validate(parse_json(data))
    except ValidationError as exc:
        raise InvalidInput(_validation_detail(exc)) from exc


def _npz_options(z: dict[str, np.ndarray]) -> dict | None:
    """The refine options among an npz's arrays (scalars eps, max_iterations, relief_iterations), validated
    like the JSON request's `options`; None when it has none."""
    given = {k: z[k] for k in RefineOptions.model_fields if k in z}
    if not given:
        return None
    for k, a in given.items():
        if a.shape != () or a.dtype.kind not in "iuf":
            raise InvalidInput(f"expected a numeric scalar, got dtype {a.dtype} and shape {a.shape}", k)
    try:
        return RefineOptions.model_validate({k: a.item() for k, a in given.items()}).model_dump()
    except ValidationError as exc:
        raise InvalidInput(_validation_detail(exc)) from exc


FRAME_ANSWERS = {200: {"description": "frames (T, N, 3)", "content": {
    JSON: {"schema": {"$ref": "#/components/schemas/AnimateResponse"}}, NPZ: BINARY, FRAMES: BINARY}}, **ERRORS}


@router.post("/animate", responses=FRAME_ANSWERS, openapi_extra={"requestBody": {"required": True, "content": {
    JSON: {"schema": {"$ref": "#/components/schemas/AnimateRequest"}}}}})
async def animate_outfit(request: Request) -> Response:
    """Outfit (or outfit_id) + motion (+ refine) -> posed vertices (T, N, 3): JSON, npz or a frame stream."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ, FRAMES])
    if media_type(request) not in (JSON, ""):
        raise UnsupportedMediaType(f"send {JSON}, not {media_type(request)!r}", "Content-Type")
    req = _parse(AnimateRequest, await read_body(request))
    settings, engine = settings_of(request), engine_of(request)
    plan = await run_in_threadpool(handlers.plan_animation, engine, settings, req.model_dump(), answer == FRAMES)

    def chunks() -> Iterator[np.ndarray]:
        return engine.pose_chunks(plan.outfit, plan.poses, plan.translation, settings.stream_chunk_frames,
                                  refine=plan.refine)

    build = partial(_frames_answer, answer, chunks, plan.outfit.faces, len(plan.outfit.vertices), plan.num_frames,
                    plan.fps, plan.outfit.outfit_id, request.app.state.metrics)
    return build() if answer == FRAMES else await run_in_threadpool(build)


refine_router = APIRouter(prefix="/v1", tags=["refine"])


@refine_router.post("/refine", responses=FRAME_ANSWERS, openapi_extra={"requestBody": {"required": True, "content": {
    JSON: {"schema": {"$ref": "#/components/schemas/RefineRequest"}},
    NPZ: {"schema": {"type": "string", "format": "binary", "description":
                     "npz: vertices (T, N, 3), faces (F, 3), poses (T, 24, 3) or (T, 72) with optional translation "
                     "(T, 3) and fps, or clip (a name); optional body, and the options as scalars: eps, "
                     "max_iterations, relief_iterations"}}}}})
async def refine_stream(request: Request) -> Response:
    """Garment stream + faces + body motion -> the stream with body penetration removed (same formats as animate)."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ, FRAMES])
    kind = media_type(request)
    settings, engine = settings_of(request), engine_of(request)
    if kind == NPZ:
        try:
            z = decode_npz(await read_body(request))
        except ValueError as exc:
            raise MalformedInput(str(exc), "body") from exc
        missing = [k for k in ("vertices", "faces") if k not in z] + ([] if "poses" in z or "clip" in z else ["poses"])
        if missing:
            raise InvalidInput(f"the archive lacks {missing}", "body")
        motion = {"clip": str(z["clip"]) if "clip" in z else None, "poses": z.get("poses"),
                  "translation": z.get("translation"), "fps": float(z.get("fps", 30.0))}
        args = (z["vertices"], z["faces"], motion, str(z["body"]) if "body" in z else None, _npz_options(z))
    elif kind in (JSON, ""):
        req = _parse(RefineRequest, await read_body(request))
        d = req.model_dump()
        args = (d["vertices"], d["faces"], d["motion"], d["body"], d["options"])
    else:
        raise UnsupportedMediaType(f"send {JSON} or {NPZ}, not {kind!r}", "Content-Type")
    plan = await run_in_threadpool(handlers.plan_refine, settings, *args, answer == FRAMES)

    def chunks() -> Iterator[np.ndarray]:
        return engine.refine_chunks(plan.vertices, plan.faces, plan.body, plan.poses, plan.translation, plan.options,
                                    settings.stream_chunk_frames)

    build = partial(_frames_answer, answer, chunks, plan.faces, plan.vertices.shape[1], len(plan.vertices), plan.fps,
                    "", request.app.state.metrics)
    return build() if answer == FRAMES else await run_in_threadpool(build)
