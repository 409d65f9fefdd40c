"""Running the app under uvicorn with the server-side limits from the settings: a bounded number of
connections (a 503 past it), a deadline for each request's line and headers (half-open and slow-header
connections are closed), keep-alive and a bounded grace period on SIGTERM."""

from __future__ import annotations

import asyncio
import socket
import struct
from typing import Any

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from drape.service.answers import ABORT_CONNECTION
from drape.service.settings import Settings


class HeaderDeadlineH11(H11Protocol):
    """uvicorn's h11 protocol, plus: a connection that has not sent a whole request head within
    `header_timeout_s` of opening (or of its previous answer's end) is closed. uvicorn alone keeps a
    connection that sends nothing, or a byte at a time, open forever. Each request's scope carries
    extensions[ABORT_CONNECTION], which resets the connection (`drop`): an answer cut because its client stopped
    reading drops the connection with it (uvicorn's close waits for the unsent bytes to go, i.e. for the client)."""

    header_timeout_s = 10.0

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm(None)
        app = self.app

        async def with_abort(scope: Any, receive: Any, send: Any) -> None:
            scope.setdefault("extensions", {})[ABORT_CONNECTION] = lambda: drop(transport)
            await app(scope, receive, send)

        self.app = with_abort

    def _arm(self, cycle: object) -> None:
        self._head_deadline = self.loop.call_later(self.header_timeout_s, self._head_late, cycle)

    def _head_late(self, cycle: object) -> None:
        """No new request head since `cycle` (None: since the connection opened): close the connection."""
        if self.cycle is cycle and not self.transport.is_closing():
            self.transport.close()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._head_deadline.cancel()
        self._arm(self.cycle)

    def connection_lost(self, exc: Exception | None) -> None:
        self._head_deadline.cancel()
        super().connection_lost(exc)


def drop(transport: asyncio.Transport) -> None:
    """Reset the connection: SO_LINGER 0, then abort, so that neither this process nor the kernel keeps its unsent
    bytes for a client that stopped reading (a plain close sends them first, i.e. waits for it)."""
    sock = transport.get_extra_info("socket")
    if sock is not None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        except (OSError, AttributeError):
            pass
    transport.abort()


def server_config(app: object, settings: Settings, log_level: str = "info") -> uvicorn.Config:
    """The uvicorn configuration drape serves with (`drape serve`, the container, the tests' live server)."""
    protocol = type("HeaderDeadlineH11", (HeaderDeadlineH11,), {"header_timeout_s": settings.header_timeout_s})
    return uvicorn.Config(app, host=settings.host, port=settings.port, http=protocol,  # type: ignore[arg-type]
                          limit_concurrency=settings.limit_concurrency,
                          timeout_keep_alive=settings.timeout_keep_alive_s,
                          timeout_graceful_shutdown=settings.shutdown_grace_s, log_level=log_level)


def serve(settings: Settings) -> None:
    """Serve the app until SIGINT/SIGTERM (then in-flight requests get `shutdown_grace_s`)."""
    from drape.service.app import create_app

    uvicorn.Server(server_config(create_app(settings), settings)).run()
