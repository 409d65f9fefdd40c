"""HTTP plumbing shared by the routers: reading bodies within the limit, the engine, auth."""

from __future__ import annotations

import hmac
import json
from typing import Any

from fastapi import Request

from drape.runtime.engine import Engine
from drape.service.errors import LimitExceeded, MalformedInput, Unauthorized
from drape.service.settings import Settings


def settings_of(request: Request) -> Settings:
    return request.app.state.settings


def engine_of(request: Request) -> Engine:
    return request.app.state.engine


async def read_body(request: Request) -> bytes:
    """The request body, refused with a 413 problem as soon as it passes DRAPE_MAX_BODY_BYTES."""
    limit = settings_of(request).max_body_bytes
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit:
        raise LimitExceeded(f"{declared} bytes exceed the limit of {limit} bytes", "body")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise LimitExceeded(f"more than the limit of {limit} bytes", "body")
        chunks.append(chunk)
    return b"".join(chunks)


def parse_json(data: bytes) -> Any:
    try:
        return json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise MalformedInput(f"not valid JSON ({exc})", "body") from exc


def media_type(request: Request) -> str:
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


async def require_api_key(request: Request) -> None:
    """When DRAPE_API_KEY is set, every /v1 route needs `Authorization: Bearer <key>`."""
    key = settings_of(request).api_key
    if not key:
        return
    given = request.headers.get("authorization", "")
    if not (given.startswith("Bearer ") and hmac.compare_digest(given[7:].encode(), key.encode())):
        raise Unauthorized("send the API key as 'Authorization: Bearer <key>'", "Authorization")
