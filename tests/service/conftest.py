"""A service on a freshly initialised exported model, with small limits so generated requests stay fast."""

import socket
import threading
import time

import pytest
import uvicorn
from fastapi.testclient import TestClient
from svc_env import test_settings

from drape.service.app import create_app


@pytest.fixture(scope="session")
def settings():
    return test_settings()


@pytest.fixture(scope="session")
def app(settings):
    app = create_app(settings)
    with TestClient(app):  # runs the lifespan: engine loaded and warmed
        yield app


@pytest.fixture
def http(app):
    return TestClient(app)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def server_url(settings):
    """A real uvicorn server on loopback, for the client round trips."""
    port = _free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.time() + 60
    while not server.started and time.time() < deadline:
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(timeout=10)
