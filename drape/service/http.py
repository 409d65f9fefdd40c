"""HTTP plumbing shared by the routers: reading bodies within the size and time limits, multipart
forms and JSON from the bytes read, the engine and the admission control, auth, HEAD answered as GET."""

from __future__ import annotations

import asyncio
import hmac
import json
from dataclasses import dataclass
from typing import Any

from fastapi import Request
from python_multipart.exceptions import FormParserError
from python_multipart.multipart import MAX_BOUNDARY_LENGTH, MultipartParser, parse_options_header
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drape.runtime.engine import Engine
from drape.service.admission import Admission
from drape.service.errors import (
    InvalidInput,
    LimitExceeded,
    MalformedInput,
    RequestTimeout,
    Unauthorized,
    UnsupportedMediaType,
    field_name,
)
from drape.service.settings import Settings


def settings_of(request: Request) -> Settings:
    return request.app.state.settings


def engine_of(request: Request) -> Engine:
    return request.app.state.engine


def admission_of(request: Request) -> Admission:
    return request.app.state.admission


async def read_body(request: Request) -> bytes:
    """The request body: a 413 problem as soon as it passes DRAPE_MAX_BODY_BYTES (declared or sent), a 408
    when it has not all arrived within DRAPE_BODY_TIMEOUT_S."""
    encoding = request.headers.get("content-encoding", "identity").strip().lower()
    if encoding not in ("", "identity"):  # a gzip body read as JSON said "not valid JSON (... byte 0x8b ...)"
        raise UnsupportedMediaType(f"the body is {encoding[:40]!r}-encoded; send it unencoded (the upload limits "
                                   "count the bytes as sent)", "Content-Encoding")
    settings = settings_of(request)
    limit = settings.max_body_bytes
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit:
        raise LimitExceeded(f"{declared} bytes exceed the limit of {limit} bytes", "body")
    chunks, size = [], 0

    async def receive_all() -> None:
        nonlocal size
        async for chunk in request.stream():
            size += len(chunk)
            if size > limit:
                raise LimitExceeded(f"more than the limit of {limit} bytes", "body")
            chunks.append(chunk)

    try:
        await asyncio.wait_for(receive_all(), settings.body_timeout_s)
    except TimeoutError:
        raise RequestTimeout(f"{size} bytes arrived in {settings.body_timeout_s:g} s, not the whole body",
                             "body") from None
    return b"".join(chunks)


@dataclass(frozen=True)
class FormPart:
    """One part of a multipart form: its file name (None for a plain field) and its bytes."""

    filename: str | None
    data: bytes


def parse_form(body: bytes, content_type: str, max_parts: int = 16) -> dict[str, FormPart]:
    """A multipart/form-data body (already read within the limits) -> its parts by name; a 400 for a broken
    form (one without its closing boundary too), a 422 for a field given more than once. Pure CPU work: call it off the event loop."""
    _, params = parse_options_header(content_type.encode("latin-1", "replace"))
    boundary = params.get(b"boundary")
    if not boundary:
        raise MalformedInput("multipart/form-data without a boundary", "Content-Type")
    if len(boundary) > MAX_BOUNDARY_LENGTH:
        raise MalformedInput(f"a boundary of {len(boundary)} characters, over the {MAX_BOUNDARY_LENGTH} the form "
                             "parser takes (RFC 2046: at most 70)", "Content-Type")
    parts: dict[str, FormPart] = {}
    headers: dict[bytes, bytes] = {}
    field, value, data = bytearray(), bytearray(), bytearray()

    def on_header_end() -> None:
        headers[bytes(field).lower()] = bytes(value)
        field.clear()
        value.clear()

    def on_part_end() -> None:
        _, disposition = parse_options_header(headers.get(b"content-disposition", b""))
        name = disposition.get(b"name", b"").decode("utf-8", "replace")
        filename = disposition.get(b"filename")
        if len(parts) >= max_parts:
            raise MalformedInput(f"more than {max_parts} parts", "body")
        if name in parts:
            raise InvalidInput("the form gives this field more than once", name[:40])
        parts[name] = FormPart(filename.decode("utf-8", "replace") if filename is not None else None, bytes(data))
        headers.clear()
        data.clear()

    ended: list[bool] = []
    callbacks = {
        "on_end": lambda: ended.append(True),
        "on_header_field": lambda b, start, end: field.extend(b[start:end]),
        "on_header_value": lambda b, start, end: value.extend(b[start:end]),
        "on_header_end": on_header_end,
        "on_part_data": lambda b, start, end: data.extend(b[start:end]),
        "on_part_end": on_part_end,
    }
    try:
        parser = MultipartParser(boundary, callbacks)  # type: ignore[arg-type]
        parser.write(body)
        parser.finalize()
    except FormParserError as exc:  # MultipartParseError and the parser's other refusals
        raise MalformedInput(f"not a readable multipart form ({exc})", "body") from exc
    if not ended:  # the parser drops a last part it never saw end: a form cut short lost a field without a word
        raise MalformedInput("the form ends before its closing boundary (--boundary--): it was cut short, and its "
                             "last field would be lost", "body")
    return parts


class DuplicateKey(ValueError):
    """A JSON object names one key twice (json.loads keeps the last, silently): `key` names it."""

    def __init__(self, key: str) -> None:
        super().__init__(f"the JSON object gives {key[:40]!r} more than once")
        self.key = key


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateKey(key)
        out[key] = value
    return out


def _duplicate_path(data: bytes | str) -> tuple | None:
    """Where in a JSON document (already parsed once, so well formed) an object first gives a key twice:
    (key, index, ..., key), or None."""

    class Twice(dict):
        key: str

    def mark(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                out = Twice(pairs)
                out.key = key
                return out
            seen.add(key)
        return dict(pairs)

    stack: list[tuple[tuple, Any]] = [((), json.loads(data, object_pairs_hook=mark))]
    while stack:  # without recursion: the document may nest as deep as json.loads allows
        path, value = stack.pop()
        if isinstance(value, Twice):
            return (*path, value.key)
        if isinstance(value, dict):
            stack.extend(((*path, k), v) for k, v in value.items())
        elif isinstance(value, list):
            stack.extend(((*path, i), v) for i, v in enumerate(value))
    return None


def loads(data: bytes | str) -> Any:
    """json.loads that refuses an object naming a key twice (DuplicateKey), as a form field or npz member given
    twice is refused: `{"refine": true, "refine": false}` was read as false without a word."""
    return json.loads(data, object_pairs_hook=_unique_keys)


def parse_json(data: bytes, field: str = "body") -> Any:
    """JSON -> Python objects; a 400 naming the problem (and `field`: the body, or a form field holding JSON
    text) for broken or too deeply nested documents, a 422 naming the key an object gives twice."""
    try:
        return loads(data)
    except RecursionError:
        raise MalformedInput("JSON nested too deeply", field) from None
    except DuplicateKey as exc:  # the key's path in a request body; the form field that holds the JSON text otherwise
        path = _duplicate_path(data) if field == "body" else None
        raise InvalidInput(str(exc), (field_name(path) if path else exc.key)[:80] if field == "body" else field
                           ) from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise MalformedInput(f"not valid JSON ({str(exc)[:200]})", field) from exc


def media_type(request: Request) -> str:
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


async def require_api_key(request: Request) -> None:
    """When DRAPE_API_KEY is set, every /v1 route needs `Authorization: Bearer <key>` (the scheme's name in any
    case, RFC 9110 11.1)."""
    key = settings_of(request).api_key
    if not key:
        return
    scheme, _, token = request.headers.get("authorization", "").partition(" ")
    if not (scheme.lower() == "bearer" and hmac.compare_digest(token.encode(), key.encode())):
        raise Unauthorized("send the API key as 'Authorization: Bearer <key>'", "Authorization")

class HeadAsGet:
    """ASGI middleware: a HEAD request is answered as its GET, without the body (RFC 9110 9.3.2: HEAD wherever
    GET is served; FastAPI's routes answered HEAD with a 405). Paths without a GET answer their 405."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("method") != "HEAD":
            await self.app(scope, receive, send)
            return

        inner = {**scope, "method": "GET"}

        async def bodiless_send(message: Message) -> None:
            if message["type"] == "http.response.start" and "route" in inner:
                scope["route"] = inner["route"]  # the router's match, for CountRequests' route label
            if message["type"] == "http.response.body":
                message = {**message, "body": b""}
            await send(message)

        await self.app(inner, receive, bodiless_send)
