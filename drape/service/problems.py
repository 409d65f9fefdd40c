"""RFC 9457 problem documents: the mapping from domain errors to HTTP, the responses, and the
last-resort guard that turns any unhandled exception into a 500 problem on a usable connection."""

from __future__ import annotations

import json
import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drape.schemas.outfits import Problem
from drape.service import errors

PROBLEM = "application/problem+json"
BASE = "https://drape.dev/problems/"
MAX_DETAIL = 1000  # characters of a problem's detail
MAX_FIELD = 200  # characters of a problem's field (a quoted unknown form field can be long)
log = logging.getLogger("drape.service")

# error class -> (status, stable type, title)
MAPPING: dict[type[errors.DrapeError], tuple[int, str, str]] = {
    errors.MalformedInput: (400, "malformed-input", "Malformed input"),
    errors.Unauthorized: (401, "unauthorized", "Missing or wrong API key"),
    errors.NotFound: (404, "not-found", "Not found"),
    errors.NotAcceptable: (406, "not-acceptable", "No acceptable answer format"),
    errors.RequestTimeout: (408, "request-timeout", "The request body came too slowly"),
    errors.Conflict: (409, "conflict", "Conflict"),
    errors.LimitExceeded: (413, "limit-exceeded", "Request exceeds a limit"),
    errors.UnsupportedMediaType: (415, "unsupported-media-type", "Unsupported request format"),
    errors.InvalidInput: (422, "invalid-input", "Invalid input"),
    errors.StoreIsFull: (507, "store-full", "Store full"),
    errors.Overloaded: (503, "overloaded", "Busy: retry later"),
}


def _document(status: int, type_: str, title: str, detail: str, field: str | None = None) -> dict:
    if len(detail) > MAX_DETAIL:
        detail = detail[:MAX_DETAIL] + "..."
    if field is not None and len(field) > MAX_FIELD:
        field = field[:MAX_FIELD] + "..."
    return Problem(type=BASE + type_, title=title, status=status, detail=detail, field=field).model_dump()


def problem(status: int, type_: str, title: str, detail: str, headers: dict | None = None,
            field: str | None = None) -> JSONResponse:
    return JSONResponse(_document(status, type_, title, detail, field), status_code=status, media_type=PROBLEM,
                        headers=headers)


def from_error(exc: errors.DrapeError) -> JSONResponse:
    status, type_, title = MAPPING[type(exc)]
    headers = None
    if isinstance(exc, errors.Unauthorized):
        headers = {"WWW-Authenticate": "Bearer"}
    elif isinstance(exc, errors.Overloaded):
        headers = {"Retry-After": str(exc.retry_after_s)}
    return problem(status, type_, title, exc.detail, headers, exc.field)


# what each status means on the routes that declare it (the OpenAPI responses' descriptions)
WHEN: dict[int, str] = {
    400: "malformed-input: the body cannot be read (broken JSON, npz, multipart form or mesh file)",
    401: "unauthorized: the service has an API key (DRAPE_API_KEY) and the request's 'Authorization: Bearer "
         "<key>' is missing or wrong",
    404: "not-found: an unknown name or id (body, garment, combination, clip, outfit_id: ids leave the cache; "
         "rig again)",
    406: "not-acceptable: no media type in Accept is one this route answers",
    408: "request-timeout: the request body did not arrive within DRAPE_BODY_TIMEOUT_S",
    409: "conflict: the request conflicts with the resource (a preset body cannot be deleted)",
    413: "limit-exceeded: over a configured limit, named in the detail: the body's bytes, vertices, faces, frames, "
         "or the answer's size in the asked format (ask for npz or the frame stream)",
    415: "unsupported-media-type: a Content-Type this route does not take",
    422: "invalid-input: well-formed but wrong (a shape, a non-finite number, an index out of range, a value "
         "out of its bounds, a mesh not on the body); the detail names the field",
    503: "overloaded: every computing slot and queue place is taken; retry after Retry-After seconds",
    507: "store-full: the user body store is full (DRAPE_MAX_BODIES bodies, DRAPE_MAX_BODY_STORE_BYTES); delete one first",
}
HEADERS: dict[int, dict] = {
    401: {"WWW-Authenticate": {"description": "Bearer", "schema": {"type": "string"}}},
    503: {"Retry-After": {"description": "seconds to wait before retrying", "schema": {"type": "integer"}}},
}


def problem_responses(*statuses: int) -> dict[int | str, dict]:
    """OpenAPI `responses` entries declaring problem+json bodies for the given statuses, each described by
    what it means (WHEN) and with its headers (Retry-After on a 503, WWW-Authenticate on a 401)."""
    schema = {"$ref": "#/components/schemas/Problem"}
    return {s: {"description": f"problem details (RFC 9457), {WHEN[s]}", "content": {PROBLEM: {"schema": schema}},
                **({"headers": HEADERS[s]} if s in HEADERS else {})}
            for s in statuses}


class CatchAll:
    """ASGI middleware: an exception that escapes the app becomes a 500 problem+json (logged once, with
    its traceback) instead of reaching the server, which would answer text/plain and drop the
    connection. An exception after the answer has started (a stream cut mid-way) can only be logged."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        except ClientDisconnect:  # the client went away while sending its body: nobody to answer
            return
        except Exception as exc:  # the last resort: never let the server see it
            log.exception("unhandled error on %s %s", scope.get("method"), scope.get("path"))
            if started:
                return
            body = json.dumps(_document(500, "internal-error", "Internal server error",
                                        f"an unexpected {type(exc).__name__}; the error is logged")).encode()
            await send({"type": "http.response.start", "status": 500,
                        "headers": [(b"content-type", PROBLEM.encode()), (b"content-length", str(len(body)).encode())]})
            await send({"type": "http.response.body", "body": body})


METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")


def allowed_methods(app: ASGIApp, scope: Scope) -> list[str]:
    """The methods some route answers at the request's path: a path served by several routes (GET and POST
    /v1/bodies, GET and DELETE /v1/bodies/{name}) gets them all in its 405's Allow, where Starlette names only
    the first route's (RFC 9110: Allow lists what the resource supports). Each method is tried against the
    app's routes (included routers too) as the router would match it."""
    routes = getattr(app, "routes", ())
    found = [m for m in METHODS if any(route.matches({**scope, "method": m})[0] == Match.FULL for route in routes)]
    return found + ["HEAD"] if "GET" in found and "HEAD" not in found else found  # HEAD as GET (http.HeadAsGet)


def install(app: FastAPI) -> None:
    """Every error becomes problem+json: domain errors, validation errors, routing errors, the unexpected."""

    @app.exception_handler(errors.DrapeError)
    async def _domain(request: Request, exc: errors.DrapeError) -> JSONResponse:
        return from_error(exc)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        parts, fields = [], []
        for e in exc.errors()[:5]:
            loc = ".".join(str(x) for x in e.get("loc", ()) if x != "body")
            parts.append(f"{loc or 'body'}: {e.get('msg')}")
            fields.append(loc or "body")
        return problem(422, "invalid-input", "Invalid input", "; ".join(parts), field=fields[0] if fields else None)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        # keeps the exception's headers: Allow on a 405, naming every route of the path
        headers = dict(exc.headers) if exc.headers else None
        if exc.status_code == 405:
            allowed = allowed_methods(request.app, request.scope)
            if allowed:
                headers = {**(headers or {}), "Allow": ", ".join(allowed)}
        return problem(exc.status_code, f"http-{exc.status_code}", str(exc.detail), str(exc.detail), headers)

    app.add_middleware(CatchAll)
