"""One freshly initialised exported model per test session, and the small-limit settings around it."""

import functools
import socket
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import uvicorn

from drape.export.deepsd import export_deepsd_from_checkpoints
from drape.service.app import create_app
from drape.service.server import server_config
from drape.service.settings import Settings


@functools.cache
def test_settings() -> Settings:
    out = Path(tempfile.mkdtemp(prefix="drape-model-"))
    export_deepsd_from_checkpoints("unused", out, init=True)
    return Settings(model_dir=out, max_vertices=3000, max_faces=6000, max_frames=200,
                    max_posed_values=300_000, max_json_values=600_000, max_body_bytes=4 * 2**20, outfit_cache_bytes=64 * 2**20)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def live_server(settings):
    """A real uvicorn server (drape's server configuration) on a free loopback port: yields its URL."""
    port = _free_port()
    server = uvicorn.Server(server_config(create_app(settings), settings.model_copy(update={"port": port}), "warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.time() + 60
    while not server.started and time.time() < deadline:
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)
