"""The service skeleton: health, readiness, catalogue, through the real client and a real server."""

import socket
import subprocess
import sys
import threading
import time

import httpx
import pytest
import uvicorn
from fastapi.testclient import TestClient

from drape import Client
from drape.geometry.skeleton import JOINT_NAMES
from drape.service.app import create_app


@pytest.fixture(scope="module")
def client():
    with TestClient(create_app()) as c:
        yield c


def test_health_and_ready(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json() == {"status": "ready"}


def test_readyz_is_503_before_startup():
    app = create_app()  # lifespan not run: assets not loaded yet
    r = TestClient(app).get("/readyz")
    assert r.status_code == 503


def test_bodies_list_three_presets_in_smpl_order(client):
    bodies = {b["name"]: b for b in client.get("/v1/bodies").json()["bodies"]}
    assert {"neutral", "female", "male"} <= set(bodies)
    for b in bodies.values():
        assert b["joint_names"] == list(JOINT_NAMES)
        assert b["parents"][0] == -1 and len(b["rest_joints"]) == 24
        assert b["num_vertices"] > 10000 and 1000 <= b["proxy_vertices"] <= 2000


def test_motions_list(client):
    motions = client.get("/v1/motions").json()["motions"]
    assert len(motions) >= 15
    walk = next(m for m in motions if m["name"] == "walk")
    assert walk["fps"] == 30.0 and walk["frames"] >= 90


def test_openapi_names_the_routes(client):
    paths = client.get("/openapi.json").json()["paths"]
    assert {"/healthz", "/readyz", "/v1/bodies", "/v1/motions"} <= set(paths)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_real_server_through_the_client():
    port = _free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.time() + 20
        while not server.started and time.time() < deadline:
            time.sleep(0.05)
        with Client(f"http://127.0.0.1:{port}") as c:
            assert c.health().status == "ok"
            assert [b.name for b in c.bodies().bodies] == ["female", "male", "neutral"]
            assert any(m.name == "walk" for m in c.motions().motions)
        with pytest.raises(httpx.HTTPStatusError):
            httpx.get(f"http://127.0.0.1:{port}/v1/nothing").raise_for_status()
    finally:
        server.should_exit = True
        thread.join(timeout=10)


def test_serving_path_imports_no_torch():
    code = (
        "import sys; import drape.service.app, drape.client, drape.geometry.metrics, drape.assets.outfits;"
        "drape.service.app.create_app();"
        "bad = [m for m in sys.modules if m == 'torch' or m.startswith('torch.')];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
