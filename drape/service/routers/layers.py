"""Two garments worn together: GET /v1/layers (the served combinations) and POST /v1/layers/animate (both layers
along a motion). Each template's rest mesh is served by GET /v1/garments/{name}.

The POST route is heavy: like animate it reads the body within the limits, takes a computing slot (503 +
Retry-After when the service is full) and checks and computes off the event loop; the work is in
drape.service.layers and Engine.layer_chunks.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from fastapi import APIRouter, Request, Response

from drape.schemas.binary import FRAMES, NPZ
from drape.schemas.gltf import GLB
from drape.schemas.layers import LayerList
from drape.schemas.pc2 import PC2
from drape.service import decode
from drape.service import layers as handlers
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
    PC2_ANSWER,
    STREAM_FORMATS,
    VERTEX_GLB,
    WARNINGS_ANSWER,
    max_posed,
    npz_answer,
    stream_answer,
    vertex_animation_answer,
    whole_answer,
)

router = APIRouter(prefix="/v1/layers", tags=["layers"])
FORM = "multipart/form-data"


@router.get("", response_model=LayerList, responses=problem_responses(401))
def list_layers(request: Request) -> LayerList:
    """The served combinations of an inner and an outer garment template: names, body, the inner thicknesses
    served ([min, max], metres) and what poses them (`model`)."""
    return handlers.layer_list(engine_of(request))


@router.post("/animate", responses={200: {
    "description": "both layers' frames: JSON or npz (inner_vertices (T, Ni, 3), inner_faces, outer_vertices "
                   "(T, No, 3), outer_faces); the frame stream, PC2 or GLB (a vertex animation) of the two as one "
                   "mesh, inner first (the frame stream's header names the ranges in `layers`)", "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/LayersAnimateResponse"}},
        NPZ: npz_answer("inner, outer (text), fps (scalar), inner_vertices (T, Ni, 3) and outer_vertices (T, No, 3) "
                        "float32 metres, inner_faces (Fi, 3), outer_faces (Fo, 3)"),
        FRAMES: FRAMES_ANSWER, PC2: PC2_ANSWER, GLB: VERTEX_GLB}, "headers": WARNINGS_ANSWER}, **ERRORS},
    openapi_extra={"requestBody": {"required": True, "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/LayersAnimateRequest"}},
        FORM: {"schema": {"type": "object", "required": ["motion_file", "request"], "properties": {
            "motion_file": {**MOTION_FILE, "description": MOTION_FILE["description"] + "; retargeted onto the "
                            "combination's body"},
            "fps": FORM_FPS, "up": FORM_UP,
            "request": {"type": "string", "contentMediaType": JSON, "description":
                        "the rest of the request as JSON text (LayersFields: inner, outer, thickness, refine)"}}}}}}})
async def animate_layers(request: Request) -> Response:
    """An inner and an outer template worn together (a combination of GET /v1/layers), the inner's thickness
    (m) and a motion (+ refine) -> both layers' vertices, world space, metres. Each layer is posed by what
    GET /v1/layers names (`inner_model`, `outer_model`: MGN's inner network, MGN's outer Transformer reading the
    inner layer and the thickness, or DeePSD's served rig); `refine` runs the post step between layers: both out
    of the body, the outer kept thickness + 1 mm outside the inner (drape.geometry.layers)."""
    answer = choose(request.headers.get("accept"), STREAM_FORMATS)
    kind = media_type(request)
    if kind not in (JSON, "", FORM):
        raise UnsupportedMediaType(f"send {JSON} or {FORM} (with a motion_file), not {kind!r}", "Content-Type")
    settings, engine = settings_of(request), engine_of(request)
    data = await read_body(request)
    content_type = request.headers.get("content-type", "")

    def plan() -> handlers.LayersPlan:
        return handlers.plan_layers(settings, engine, decode.layers_request(data, settings, engine, kind, content_type),
                                    max_posed(answer, settings))

    def pairs(p: handlers.LayersPlan) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        return engine.layer_chunks(p.combination, p.thickness, p.poses, p.translation,
                                   settings.stream_chunk_frames, refine=p.refine, fps=p.fps)

    def source() -> FrameSource:
        p = plan()
        c = p.combination
        ni, no = c.inner.num_vertices, c.outer.num_vertices
        faces = np.concatenate([c.inner.faces, c.outer.faces + ni]).astype(np.int32)

        def chunks() -> Iterator[np.ndarray]:
            return (np.concatenate([i, o], axis=1) for i, o in pairs(p))

        layers = [{"name": c.inner.name, "start": 0, "stop": ni}, {"name": c.outer.name, "start": ni, "stop": ni + no}]
        return FrameSource(chunks, faces, p.num_frames, ni + no, p.fps, "", layers)

    if answer == GLB:
        def glb() -> Response:
            return vertex_animation_answer(source(), settings, kind, "motion", name="layers")

        return await whole_answer(request, glb)
    return await stream_answer(request, answer, source)
