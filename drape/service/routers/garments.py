"""The intrinsic garment space (Wang et al. 2019) of the served garment templates:

GET /v1/garments, GET /v1/garments/{name} (the template mesh), POST /v1/garments/{name}/encode (a keyframe shape
-> its latent), .../animate (keyframes + motion -> the garment's stream, every answer format of
/v1/outfits/animate) and .../sample (design candidates at a frame).

The POST routes are heavy: like rig and animate they read the body within the limits, take a computing slot
(a 503 + Retry-After when the service is full) and decode, validate and compute off the event loop; the work
is in drape.service.garments.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from fastapi import APIRouter, Path, Request, Response
from fastapi.responses import JSONResponse

from drape.runtime.engine import Engine
from drape.runtime.intrinsic import IntrinsicGarment
from drape.schemas.binary import FRAMES, NPZ, encode_npz
from drape.schemas.garments import GarmentList
from drape.schemas.gltf import GLB
from drape.schemas.pc2 import PC2
from drape.service import decode
from drape.service import garments as handlers
from drape.service.answers import JSON, FrameSource
from drape.service.errors import UnsupportedMediaType
from drape.service.http import engine_of, media_type, read_body, settings_of
from drape.service.negotiate import choose
from drape.service.problems import problem_responses
from drape.service.routers.outfits import (
    ERRORS,
    FORM_FPS,
    FORM_UP,
    FRAMES_ANSWER,
    MOTION_FILE,
    MOTION_NPZ,
    PC2_ANSWER,
    STREAM_FORMATS,
    STREAM_NPZ,
    VERTEX_GLB,
    WARNINGS_ANSWER,
    max_posed,
    npz_answer,
    stream_answer,
    vertex_animation_answer,
    whole_answer,
)
from drape.service.settings import Settings

router = APIRouter(prefix="/v1/garments", tags=["garments"])
NAME = Path(description="the garment template's name (GET /v1/garments)")
BODY_KINDS = (JSON, NPZ, "multipart/form-data", "")
MOTION_NPZ_HELP = f"the motion: {MOTION_NPZ}"


def _form(fields_model: str, help: str) -> dict:
    return {"schema": {"type": "object", "required": ["motion_file", "request"], "properties": {
        "motion_file": {**MOTION_FILE, "description": MOTION_FILE["description"] + "; retargeted onto the "
                        "garment's body"},
        "fps": FORM_FPS, "up": FORM_UP,
        "request": {"type": "string", "contentMediaType": JSON, "description":
                    f"the rest of the request as JSON text ({fields_model}: {help})"}}}}


def _request_body(model: str, npz_help: str, fields_model: str, form_help: str) -> dict:
    return {"requestBody": {"required": True, "content": {
        JSON: {"schema": {"$ref": f"#/components/schemas/{model}"}},
        NPZ: {"schema": {"type": "string", "format": "binary", "description": f"npz: {MOTION_NPZ_HELP}; {npz_help}"}},
        "multipart/form-data": _form(fields_model, form_help)}}}


def _body_kind(request: Request) -> str:
    kind = media_type(request)
    if kind not in BODY_KINDS:
        raise UnsupportedMediaType(f"send {JSON}, {NPZ} or multipart/form-data, not {kind!r}", "Content-Type")
    return kind


@dataclass(frozen=True)
class _Post:
    """A garment POST, read on the event loop: what its work (off the loop) needs."""

    settings: Settings
    engine: Engine
    garment: IntrinsicGarment
    kind: str  # the body's media type, one of BODY_KINDS
    data: bytes
    content_type: str

    def decode(self, what: str):  # noqa: ANN201 (the request model of `what`)
        """The body as the `what` ("encode", "animate", "sample") request, validated (4xx on bad input)."""
        return decode.garment_request(what, self.kind, self.data, self.settings, self.garment.body,
                                      self.content_type)


async def _read_post(request: Request, name: str) -> _Post:
    """The checks every garment POST makes in this order (415 body type, 404 template, 413 body size), then the
    body read within the limits."""
    kind = _body_kind(request)
    settings, engine = settings_of(request), engine_of(request)
    garment = handlers.find(engine, name)
    return _Post(settings, engine, garment, kind, await read_body(request), request.headers.get("content-type", ""))


@router.get("", response_model=GarmentList, responses=problem_responses(401))
def list_garments(request: Request) -> GarmentList:
    """The served garment templates: name, vertex count, body, models; for intrinsic ones the frame rate, the
    motion window (past frames besides the current one), the model version and the latent size Z; then the
    layer templates (models ["deepsd"]: animated in pairs by POST /v1/layers/animate)."""
    return handlers.garment_list(engine_of(request))


@router.get("/{name}", responses={200: {"description": "the template mesh in rest pose on its body", "content": {
    JSON: {"schema": {"$ref": "#/components/schemas/GarmentTemplate"}},
    NPZ: npz_answer("name (text), body (text), vertices (N, 3) metres, faces (F, 3)")}},
    **problem_responses(401, 404, 406)})
def get_garment(request: Request, name: str = NAME) -> Response:
    """The template mesh: vertices (N, 3) metres in rest pose on its body, faces (F, 3); JSON or npz by Accept."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ])
    engine = engine_of(request)
    g = handlers.find_template(engine, name)
    if answer == NPZ:
        return Response(encode_npz({"name": np.array(g.name), "body": np.array(g.body), "vertices": g.vertices,
                                    "faces": g.faces}), media_type=NPZ)
    return JSONResponse({"name": g.name, "body": g.body, "vertices": g.vertices.tolist(), "faces": g.faces.tolist()})


@router.post("/{name}/encode", responses={200: {"description": "the keyframe's latent (Z,)", "content": {
    JSON: {"schema": {"$ref": "#/components/schemas/EncodeResponse"}}, NPZ: npz_answer("latent (Z,)")}, "headers": WARNINGS_ANSWER}, **ERRORS},
    openapi_extra=_request_body("EncodeRequest", "vertices (N, 3), frame (integer scalar)", "EncodeFields",
                                "vertices, frame"))
async def encode_keyframe(request: Request, name: str = NAME) -> Response:
    """A keyframe shape -> its latent: vertices (N, 3) m, world space at `frame` of the motion (the frames up to
    it give the motion window) -> latent (Z,): the encoder's latent pulled toward the training mean by the model's
    `keyframe_shrink` (the same latent animate gives a shape keyframe). JSON or npz (a `latent` member) by Accept."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ])
    post = await _read_post(request, name)

    def work() -> Response:
        latent = handlers.encode(post.settings, post.garment, post.decode("encode"))
        if answer == NPZ:
            return Response(encode_npz({"latent": latent}), media_type=NPZ)
        return JSONResponse({"latent": latent.tolist()})

    return await whole_answer(request, work)


@router.post("/{name}/animate", responses={200: {
    "description": "the garment's frames (T, N, 3): JSON, npz, the frame stream, PC2 (point cache) or GLB (a vertex "
                   "animation)", "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/AnimateResponse"}}, NPZ: STREAM_NPZ, FRAMES: FRAMES_ANSWER,
        PC2: PC2_ANSWER, GLB: VERTEX_GLB}, "headers": WARNINGS_ANSWER}, **ERRORS},
    openapi_extra=_request_body(
        "KeyframeAnimateRequest", "vertex_frames (Kv,) integers with vertices (Kv, N, 3) and/or latent_frames (Kl,) "
        "with latents (Kl, Z); match_keyframes (boolean scalar); refine (boolean scalar) and/or the refine options as "
        "scalars: eps, max_iterations, relief_iterations", "KeyframeFields", "keyframes, match_keyframes, refine"))
async def animate_keyframes(request: Request, name: str = NAME) -> Response:
    """Keyframes + motion (+ refine) -> the garment's vertices (T, N, 3) m, world space. A keyframe is a shape
    (vertices (N, 3), world space at its frame: encoded with the motion up to that frame) or a latent (Z,); the
    latents are interpolated linearly between keyframes (held before the first and after the last) and each
    frame is decoded with its motion window; with match_keyframes (default) shape keyframes are met exactly, what
    decoding misses of them added back and fading away from them; refinement pushes the garment out of its body. Answers as
    /v1/outfits/animate: JSON, npz, the frame stream, PC2, or GLB (the stream as a vertex animation)."""
    answer = choose(request.headers.get("accept"), STREAM_FORMATS)
    post = await _read_post(request, name)
    settings, engine, garment = post.settings, post.engine, post.garment

    def plan() -> FrameSource:
        req = post.decode("animate")
        p = handlers.plan_keyframes(settings, garment, req, max_posed(answer, settings))

        def chunks() -> Iterator[np.ndarray]:
            return engine.garment_chunks(garment, p.latents, p.poses, p.translation, settings.stream_chunk_frames,
                                         refine=p.refine, residual=p.residual, fps=p.fps)

        return FrameSource(chunks, garment.faces, p.num_frames, garment.num_vertices, p.fps, "")

    if answer == GLB:
        def glb() -> Response:
            return vertex_animation_answer(plan(), settings, post.kind, "motion", name=garment.name)

        return await whole_answer(request, glb)
    return await stream_answer(request, answer, plan)


@router.post("/{name}/sample", responses={200: {
    "description": "latents (count, Z) and their shapes (count, N, 3) at the frame", "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/SampleResponse"}},
        NPZ: npz_answer("latents (count, Z), vertices (count, N, 3) metres")}, "headers": WARNINGS_ANSWER}, **ERRORS},
    openapi_extra=_request_body("SampleRequest", "count, seed, frame (integer scalars)", "SampleFields",
                                "count, seed, frame"))
async def sample_designs(request: Request, name: str = NAME) -> Response:
    """Design candidates: `count` latents drawn from the training latents' statistics (mean + std * standard
    normal, numpy's default_rng(seed)) and their shapes (count, N, 3) m, world space at `frame` of the motion.
    JSON or npz (latents, vertices) by Accept."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ])
    post = await _read_post(request, name)

    def work() -> Response:
        max_values = post.settings.max_json_values if answer == JSON else None
        latents, vertices = handlers.sample(post.settings, post.garment, post.decode("sample"), max_values)
        if answer == NPZ:
            return Response(encode_npz({"latents": latents, "vertices": vertices}), media_type=NPZ)
        return JSONResponse({"latents": latents.tolist(), "vertices": vertices.tolist()})

    return await whole_answer(request, work)

