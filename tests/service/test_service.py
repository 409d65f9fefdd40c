"""The service skeleton: health, readiness, catalogue, through the real client and a real server."""

import subprocess
import sys

import httpx
import pytest
from fastapi.testclient import TestClient

from drape import Client
from drape.geometry.skeleton import JOINT_NAMES
from drape.service.app import create_app


@pytest.fixture
def client(http):
    return http


def test_health_and_ready(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json() == {"status": "ready"}


def test_readyz_is_503_before_startup(settings):
    app = create_app(settings)  # lifespan not run: model and assets not loaded yet
    r = TestClient(app).get("/readyz")
    assert r.status_code == 503


def test_bodies_list_three_presets_in_smpl_order(client):
    bodies = {b["name"]: b for b in client.get("/v1/bodies").json()["bodies"]}
    assert {"neutral", "female", "male"} <= set(bodies)
    for b in bodies.values():  # a user body another test registered in this process may be listed too
        assert b["joint_names"] == list(JOINT_NAMES)
        assert b["parents"][0] == -1 and len(b["rest_joints"]) == 24
        assert not b["preset"] or b["num_vertices"] > 10000 and 1000 <= b["proxy_vertices"] <= 2000


def test_motions_list(client):
    motions = client.get("/v1/motions").json()["motions"]
    assert len(motions) >= 15
    walk = next(m for m in motions if m["name"] == "walk")
    assert walk["fps"] == 30.0 and walk["frames"] >= 90


def test_openapi_names_the_routes(client):
    paths = client.get("/openapi.json").json()["paths"]
    assert {"/healthz", "/readyz", "/metrics", "/v1/bodies", "/v1/motions", "/v1/models", "/v1/models/{name}",
            "/v1/outfits/rig", "/v1/outfits/animate", "/v1/refine"} <= set(paths)


def test_real_server_through_the_client(server_url):
    with Client(server_url) as c:
        assert c.health().status == "ok"
        assert [b.name for b in c.bodies().bodies] == ["female", "heavy", "male", "neutral"]
        assert any(m.name == "walk" for m in c.motions().motions)
        assert c.models().models[0].name == "deepsd"
    with pytest.raises(httpx.HTTPStatusError):
        httpx.get(f"{server_url}/v1/nothing").raise_for_status()


def test_serving_path_imports_no_torch():
    code = (
        "import sys; import drape.service.app, drape.client, drape.runtime.engine, drape.geometry.metrics,"
        " drape.assets.outfits; drape.service.app.create_app();"
        "bad = [m for m in sys.modules if m == 'torch' or m.startswith('torch.')];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_refine_defaults_are_the_librarys():
    """`refine: true`, RefineOptions() and the library's refine() give the same refinement: one default each."""
    from drape.geometry import refine
    from drape.runtime.engine import RefineSettings
    from drape.schemas.outfits import RefineOptions

    library = {"eps": refine.EPS, "max_iterations": refine.MAX_ITERATIONS,
               "relief_iterations": refine.RELIEF_ITERATIONS}
    assert RefineOptions().model_dump() == library
    assert vars(RefineSettings()) == library
    assert refine.RELIEF_ITERATIONS > 0, "the stretch relief pass is on by default"
