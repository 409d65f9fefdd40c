"""RFC 9457 problem documents: the mapping from domain errors to HTTP, and the responses."""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from drape.schemas.outfits import Problem
from drape.service import errors

PROBLEM = "application/problem+json"
BASE = "https://drape.dev/problems/"

# error class -> (status, stable type, title)
MAPPING: dict[type[errors.DrapeError], tuple[int, str, str]] = {
    errors.MalformedInput: (400, "malformed-input", "Malformed input"),
    errors.Unauthorized: (401, "unauthorized", "Missing or wrong API key"),
    errors.NotFound: (404, "not-found", "Not found"),
    errors.NotAcceptable: (406, "not-acceptable", "No acceptable answer format"),
    errors.LimitExceeded: (413, "limit-exceeded", "Request exceeds a limit"),
    errors.UnsupportedMediaType: (415, "unsupported-media-type", "Unsupported request format"),
    errors.InvalidInput: (422, "invalid-input", "Invalid input"),
}


def problem(status: int, type_: str, title: str, detail: str, headers: dict | None = None) -> JSONResponse:
    body = Problem(type=BASE + type_, title=title, status=status, detail=detail).model_dump()
    return JSONResponse(body, status_code=status, media_type=PROBLEM, headers=headers)


def from_error(exc: errors.DrapeError) -> JSONResponse:
    status, type_, title = MAPPING[type(exc)]
    headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
    return problem(status, type_, title, exc.detail, headers)


def problem_responses(*statuses: int) -> dict[int | str, dict]:
    """OpenAPI `responses` entries declaring problem+json bodies for the given statuses."""
    schema = {"$ref": "#/components/schemas/Problem"}
    return {s: {"description": "problem details (RFC 9457)", "content": {PROBLEM: {"schema": schema}}}
            for s in statuses}


def install(app: FastAPI) -> None:
    """Every error becomes problem+json: domain errors, validation errors, routing errors, the unexpected."""

    @app.exception_handler(errors.DrapeError)
    async def _domain(request: Request, exc: errors.DrapeError) -> JSONResponse:
        return from_error(exc)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        parts = []
        for e in exc.errors()[:5]:
            loc = ".".join(str(x) for x in e.get("loc", ()) if x != "body")
            parts.append(f"{loc or 'body'}: {e.get('msg')}")
        return problem(422, "invalid-input", "Invalid input", "; ".join(parts))

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        return problem(exc.status_code, f"http-{exc.status_code}", str(exc.detail), str(exc.detail))
