"""User bodies: POST /v1/bodies (register a skinned GLB / glTF or an npz of the body's arrays),
GET /v1/bodies/{name} (any body's mesh and skeleton, JSON or npz) and DELETE /v1/bodies/{name}.

Registering reads the upload within the limits and checks it under a computing slot, off the event loop,
like the other heavy routes; the checks and documents are in drape.service.bodies.
"""

from __future__ import annotations

from fastapi import APIRouter, Path, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from drape.assets.body import list_bodies
from drape.runtime.body_store import BodyStore
from drape.schemas.binary import NPZ, encode_npz
from drape.schemas.catalog import BodyMesh, BodyRegistered
from drape.service import bodies, handlers
from drape.service.answers import JSON
from drape.service.errors import Conflict, LimitExceeded, NotFound, UnsupportedMediaType, quoted
from drape.service.http import admission_of, media_type, read_body, settings_of
from drape.service.negotiate import choose
from drape.service.problems import problem_responses

router = APIRouter(prefix="/v1/bodies", tags=["bodies"])
NAME = Path(description="a preset's name (GET /v1/bodies) or a body_id (POST /v1/bodies)")
NPZ_HELP = ("npz with vertices (V, 3) m, faces (F, 3), weights (V, 24) rows summing to 1, joints (24, 3) m; "
            "optional parents (24,) (SMPL's), joint_names (24,) (SMPL's names, any order), rest_pose (24, 3) "
            "axis-angle radians of the pose the body is given in (default: it is in T-pose)")


def store_of(request: Request) -> BodyStore:
    store: BodyStore = request.app.state.bodies
    return store


@router.post(
    "",
    status_code=201,
    response_model=BodyRegistered,
    responses={201: {"description": "the body is held; its body_id names it wherever a body is accepted",
                     "headers": {"Location": {"description": "/v1/bodies/{body_id}", "schema": {"type": "string"}}}},
               **problem_responses(400, 401, 408, 413, 415, 422, 503, 507)},
    openapi_extra={"requestBody": {"required": True, "content": {
        "multipart/form-data": {"schema": {"type": "object", "required": ["body_file"], "properties": {
            "body_file": {"type": "string", "format": "binary",
                          "description": "a GLB / glTF whose skinned mesh's 24 joints carry SMPL's names (or "
                                         "joint_map's), or an npz as the application/x-npz body"},
            "joint_map": {"type": "string", "contentMediaType": JSON,
                          "description": "JSON object: the file's joint names -> SMPL's; other joints' weights "
                                         "go to their nearest mapped ancestor"},
            "rest_pose": {"type": "string", "contentMediaType": JSON,
                          "description": "JSON (24, 3) axis-angle radians: the pose the body is given in"}}}},
        NPZ: {"schema": {"type": "string", "format": "binary", "description": NPZ_HELP}},
    }}},
)
async def register_body(request: Request) -> Response:
    """Register a user body (24 SMPL-named joints, metres, +Y up, facing +Z, T-pose or un-posed by rest_pose)."""
    kind = media_type(request)
    if kind not in ("multipart/form-data", NPZ):
        raise UnsupportedMediaType(f"send multipart/form-data (body_file) or {NPZ}, not {kind!r}", "Content-Type")
    settings, store = settings_of(request), store_of(request)
    data = await read_body(request)
    content_type = request.headers.get("content-type", "")

    def work() -> Response:
        body = bodies.read_upload(kind, content_type, data, settings)
        registrations = bodies.register(store, body)
        return JSONResponse({**bodies.summary(body), "registrations": registrations}, status_code=201,
                            headers={"Location": f"/v1/bodies/{body.name}"})

    slot = await admission_of(request).enter()
    try:
        return await run_in_threadpool(work)
    finally:
        slot.release()


@router.get(
    "/{name}",
    responses={200: {"description": "the body's mesh and skeleton", "content": {
        JSON: {"schema": {"$ref": "#/components/schemas/BodyMesh"}},
        NPZ: {"schema": {"type": "string", "format": "binary", "description": "npz with vertices (V, 3) metres, faces "
                         "(F, 3), weights (V, 24), joints (24, 3) metres, parents (24,), joint_names (24,) text"}}}},
        **problem_responses(401, 404, 406, 413)},
)
def get_body(request: Request, name: str = NAME) -> Response:
    """A body's rest mesh, weights and skeleton (npz by Accept), so a client can draw it beside a garment."""
    answer = choose(request.headers.get("accept"), [JSON, NPZ])
    body = handlers.held_body(name, "name")
    arrays = bodies.body_arrays(body)
    preset = body.name in list_bodies()
    if answer == NPZ:
        return Response(encode_npz(arrays), media_type=NPZ)
    numbers = sum(a.size for a in arrays.values())
    settings = settings_of(request)
    if numbers > settings.max_json_values:
        raise LimitExceeded(f"the body has {numbers} numbers, over the limit of {settings.max_json_values} for a "
                            "JSON answer; ask for Accept: application/x-npz", "Accept")
    doc = BodyMesh(name=body.name, preset=preset, vertices=arrays["vertices"].tolist(),
                   faces=arrays["faces"].tolist(), weights=arrays["weights"].tolist(),
                   joints=arrays["joints"].tolist(), parents=arrays["parents"].tolist(),
                   joint_names=list(body.joint_names))
    return JSONResponse(doc.model_dump())


@router.delete("/{name}", status_code=204, responses={
    204: {"description": "one registration taken back; the body is forgotten with the last"},
    **problem_responses(401, 404, 409)})
def delete_body(request: Request, name: str = NAME) -> Response:
    """Take back one registration of a user body; with the last the body is forgotten (its file too, with
    DRAPE_BODY_DIR), so a client that registered a body keeps it while another that registered the same body
    deletes it. Presets cannot be deleted. Outfits rigged on a forgotten body stay cached, but new requests naming
    it answer 404."""
    if name in list_bodies():
        raise Conflict(f"{quoted(name, 60)} is a preset: only user bodies can be deleted", "name")
    if not store_of(request).delete(name):
        raise NotFound(f"no user body {quoted(name, 60)}", "name")
    return Response(status_code=204)
