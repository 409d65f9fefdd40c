"""Warnings an answer carries beside its result: the `Drape-Warnings` response header.

A request can be done as asked and still look wrong: an uploaded motion file whose skeleton contradicts the
`up` field, feet left far from the floor. The CLI prints such sentences; over HTTP they travel in one header,
whatever the answer's format (JSON, npz, the frame stream, GLB, PC2), as a JSON array of strings (ASCII, the
other characters escaped): `Drape-Warnings: ["the feet stay 440 mm from the floor ..."]`. The Python client
raises them as `drape.client.DrapeWarning`s.

The code that notices something (it knows nothing of HTTP) calls `warn(sentence)`; `WarningsHeader`, an ASGI
middleware, gives each request its own list and adds the header to a successful answer's start. Work run off
the event loop sees the same list: starlette's run_in_threadpool copies the request's context into the thread.
"""

from __future__ import annotations

import json
from contextvars import ContextVar

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drape.schemas import WARNINGS_HEADER

__all__ = ["WARNINGS_HEADER", "WarningsHeader", "warn"]
MAX_WARNINGS = 16  # sentences kept per answer; the header stays small
MAX_SENTENCE = 400  # characters kept of a sentence (one may quote a file's text: a probe put 200 KB in the header,
# which httpx refused to read)

_current: ContextVar[list[str] | None] = ContextVar("drape_warnings", default=None)


def warn(sentence: str) -> None:
    """Add a sentence to the current request's answer (outside a request, e.g. the CLI: nothing)."""
    notes = _current.get()
    if len(sentence) > MAX_SENTENCE:
        sentence = sentence[:MAX_SENTENCE - 3] + "..."
    if notes is not None and sentence not in notes and len(notes) < MAX_WARNINGS:
        notes.append(sentence)


def header_value(notes: list[str]) -> bytes:
    """The header's value: a JSON array, ASCII (json's escapes), on one line."""
    return json.dumps(notes).encode("ascii")


class WarningsHeader:
    """ASGI middleware: each HTTP request gets its own warnings list; a successful answer (status < 400) that
    has any carries them in `Drape-Warnings`. An error answer does not: its problem document says what went
    wrong."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        notes: list[str] = []
        token = _current.set(notes)

        async def send_with_warnings(message: Message) -> None:
            if message["type"] == "http.response.start" and notes and message["status"] < 400:
                headers = [*message.get("headers", []), (WARNINGS_HEADER.lower().encode(), header_value(notes))]
                message = {**message, "headers": headers}
            await send(message)

        try:
            await self.app(scope, receive, send_with_warnings)
        finally:
            _current.reset(token)
