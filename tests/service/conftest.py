"""A service on a freshly initialised exported model, with small limits so generated requests stay fast."""

import pytest
from fastapi.testclient import TestClient
from svc_env import live_server, test_settings

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


@pytest.fixture(scope="session")
def server_url(settings):
    """A real uvicorn server on loopback, for the client round trips."""
    with live_server(settings) as url:
        yield url
