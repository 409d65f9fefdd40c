"""drape on Ray Serve: a local Ray (2 CPUs), 2 replicas of the app deployed with the test settings behind
Serve's HTTP proxy on a loopback port; the contract (schemathesis against the live URL), client round trips
through the proxy (the frame stream included), outfit ids across replicas, two replica processes.
Skipped without the `cluster` extra (ray.serve not importable)."""

import os
import shutil
import socket
import tempfile
from pathlib import Path

import httpx
import numpy as np
import pytest
import schemathesis
import yaml
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.generation import GenerationMode
from schemathesis.specs.openapi.checks import (
    negative_data_rejection,
    response_schema_conformance,
    status_code_conformance,
)
from svc_env import test_settings as svc_settings

import drape
from drape.assets.outfits import generate_outfit
from drape.geometry.mesh_io import save_mesh
from drape.schemas.binary import NPZ, decode_npz
from drape.service import ray_serve  # imports without ray
from drape.service.app import create_app

ray = pytest.importorskip("ray")
serve = pytest.importorskip("ray.serve")

REPLICAS = 2
CHECKS = [not_a_server_error, status_code_conformance, response_schema_conformance, negative_data_rejection]
EXAMPLES = 20  # per operation (positive and negative): >= 250 cases; the in-process run (test_contract.py) makes
# >= 1,000 against the same schema (test_served_schema_is_the_apps), this one checks the proxy in between
CASES = {"count": 0}
ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def url():
    """Ray on this machine (2 CPUs, its own short temp dir: Ray's socket paths must stay short), drape
    deployed on it as a cluster would run it; everything stopped afterwards."""
    if ray.is_initialized():
        pytest.skip("Ray is already initialised in this process")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # nothing leaves the machine
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, _temp_dir=temp)
    try:
        port = _free_port()
        address = ray.get_runtime_context().gcs_address
        ray_serve.deploy(address, REPLICAS, svc_settings().model_copy(update={"port": port}),
                         replica_cpus=0.5, blocking=False)
        yield f"http://127.0.0.1:{port}"
    finally:
        try:
            serve.shutdown()
        finally:
            ray.shutdown()
            shutil.rmtree(temp, ignore_errors=True)


def _replica(response: httpx.Response) -> str:
    return response.headers[ray_serve.REPLICA_HEADER]


def _answers_from_both(call, tries: int = 60) -> dict[str, httpx.Response]:
    """Repeat `call` until both replicas have answered it (Serve spreads requests over them)."""
    seen: dict[str, httpx.Response] = {}
    for _ in range(tries):
        r = call()
        seen.setdefault(_replica(r), r)
        if len(seen) == REPLICAS:
            return seen
    raise AssertionError(f"only replicas {sorted(seen)} answered {tries} requests")


def test_two_ready_replicas_in_two_processes(url):
    """Each replica ran the app's lifespan (ready: models loaded), and each is its own process."""
    seen = _answers_from_both(lambda: httpx.get(f"{url}/readyz", timeout=30))
    assert all(r.status_code == 200 and r.json() == {"status": "ready"} for r in seen.values())
    status = serve.status().applications[ray_serve.APP_NAME].deployments["drape"]
    assert status.replica_states == {"RUNNING": REPLICAS}
    # the replica actors' processes, from Ray's actor table (a replica's actor name ends in its id)
    pids = {}
    for actor in ray._private.state.actors().values():
        for rid in seen:
            if actor["State"] == "ALIVE" and actor["Name"].endswith(f"#drape#{rid}"):
                pids[rid] = actor["Pid"]
    assert len(set(pids.values())) == REPLICAS and os.getpid() not in pids.values(), pids


def test_metrics_are_per_replica(url):
    """Each replica counts its own requests (its own app and registry): the counters differ by replica."""
    def count(text: str) -> float:
        for line in text.splitlines():
            if line.startswith("drape_requests_total") and 'route="/healthz"' in line and 'status="200"' in line:
                return float(line.rsplit(" ", 1)[1])
        return 0.0

    before = {rid: count(r.text) for rid, r in _answers_from_both(lambda: httpx.get(f"{url}/metrics")).items()}
    hits: dict[str, int] = {}
    for _ in range(6):
        rid = _replica(httpx.get(f"{url}/healthz"))
        hits[rid] = hits.get(rid, 0) + 1
    after = {rid: count(r.text) for rid, r in _answers_from_both(lambda: httpx.get(f"{url}/metrics")).items()}
    assert {rid: after[rid] - before[rid] for rid in before} == {rid: float(hits.get(rid, 0)) for rid in before}


# The schema the cases are generated from is the app's own, made here (schemathesis' lazy from_fixture, which
# would load it from the live URL, does not work with pytest 9); the cases are sent to the live URL, and
# test_served_schema_is_the_apps checks that Serve serves this same schema.
APP_SCHEMA = create_app(svc_settings()).openapi()
schema = schemathesis.openapi.from_dict(APP_SCHEMA)
schema.config.generation.update(modes=[GenerationMode.POSITIVE, GenerationMode.NEGATIVE], max_examples=EXAMPLES)


def test_served_schema_is_the_apps(url):
    assert httpx.get(f"{url}/openapi.json").json() == APP_SCHEMA


@schema.parametrize()
@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
def test_api_conforms_to_its_schema_through_serve(case, url):
    CASES["count"] += 1
    case.call_and_validate(base_url=url, checks=CHECKS, timeout=60)


def test_enough_generated_cases_through_serve():
    """Runs after the schema tests in this module."""
    assert CASES["count"] >= 250, CASES["count"]


@pytest.fixture(scope="module")
def outfit():
    return generate_outfit("tshirt", vertices=1200, seed=31)


def test_client_round_trip_and_frame_stream(url, outfit, tmp_path):
    with drape.Client(url) as client:
        rig = client.rig((outfit.vertices, outfit.faces))
        assert rig.skinning_weights.shape == (len(outfit.vertices), 24)
        npz = client.animate(outfit_id=rig.outfit_id, motion="punch")
        frames = list(client.animate_stream(outfit_id=rig.outfit_id, motion="punch"))
        # a file path: the client uploads it through rig, then animates by outfit_id (maybe on the other replica)
        by_path = client.animate(outfit=save_mesh(tmp_path / "shirt.glb", outfit.vertices, outfit.faces),
                                 motion="punch")
    assert npz.ndim == 3 and npz.shape[1:] == (len(outfit.vertices), 3) and npz.dtype == np.float32
    assert np.array_equal(np.stack(frames), npz)
    assert np.abs(by_path - npz).max() < 1e-6
    body = {"outfit_id": rig.outfit_id, "motion": {"clip": "punch"}}
    js = httpx.post(f"{url}/v1/outfits/animate", json=body, timeout=60).json()
    assert np.array_equal(np.asarray(js["vertices"], np.float32), npz)


def test_outfit_id_works_on_a_replica_that_did_not_rig_it(url):
    """Rig once (replica A); animate by that outfit_id until replica B answers: B never saw the mesh and
    answers the same frames (it takes A's rig from the app's outfit store). Rigging the mesh again on B
    gives the same outfit_id (content hash)."""
    shirt = generate_outfit("tshirt", vertices=900, seed=77)  # a mesh no other test rigs
    mesh = {"vertices": shirt.vertices.tolist(), "faces": shirt.faces.tolist()}
    rigged = httpx.post(f"{url}/v1/outfits/rig", json=mesh, timeout=60)
    assert rigged.status_code == 200
    a, oid = _replica(rigged), rigged.json()["outfit_id"]

    def animate() -> httpx.Response:
        return httpx.post(f"{url}/v1/outfits/animate", json={"outfit_id": oid, "motion": {"clip": "kick"}},
                          headers={"Accept": NPZ}, timeout=60)

    answers = _answers_from_both(animate)
    assert all(r.status_code == 200 for r in answers.values()), {k: r.text[:300] for k, r in answers.items()}
    b = next(rid for rid in answers if rid != a)
    assert np.array_equal(decode_npz(answers[a].content)["vertices"], decode_npz(answers[b].content)["vertices"])
    again = _answers_from_both(lambda: httpx.post(f"{url}/v1/outfits/rig", json=mesh, timeout=60))
    assert {r.json()["outfit_id"] for r in again.values()} == {oid}
    unknown = _answers_from_both(lambda: httpx.post(
        f"{url}/v1/outfits/animate", json={"outfit_id": "0" * 32, "motion": {"clip": "kick"}}, timeout=60))
    assert {r.status_code for r in unknown.values()} == {404}


def test_serve_config_file_builds_the_application():
    """deploy/serve.yaml is a valid Serve config whose import_path builds drape's application from its args."""
    from ray.serve._private.utils import import_attr
    from ray.serve.schema import ServeDeploySchema

    config = ServeDeploySchema.model_validate(yaml.safe_load((ROOT / "deploy" / "serve.yaml").read_text()))
    (spec,) = config.applications
    assert spec.import_path == "drape.service.ray_serve:app" and spec.route_prefix == "/"
    builder = import_attr(spec.import_path)
    assert isinstance(builder(spec.args), serve.Application)
    assert isinstance(builder({"replicas": "3", "max_active": "4"}), serve.Application)  # CLI-style strings
    with pytest.raises(ValueError):
        builder({"replicas": 1, "not_a_setting": 1})
    with pytest.raises(ValueError):
        builder({"replicas": 0})


def test_replicas_refine_in_process_unless_told(monkeypatch):
    from drape.service.settings import Settings

    monkeypatch.delenv("DRAPE_REFINE_WORKERS", raising=False)
    assert ray_serve.replica_settings(Settings()).refine_workers == 1
    assert ray_serve.replica_settings(Settings(refine_workers=3)).refine_workers == 3
    monkeypatch.setenv("DRAPE_REFINE_WORKERS", "2")
    assert ray_serve.replica_settings(Settings()).refine_workers == 2


def test_cli_serve_ray_deploys(monkeypatch):
    from drape import cli

    calls = []
    monkeypatch.setattr(ray_serve, "deploy", lambda *a, **k: calls.append((a, k)))
    cli.main(["serve", "--ray", "auto", "--replicas", "3", "--port", "9123", "--replica-cpus", "0.5"])
    ((address, replicas, settings_), kwargs), = calls
    assert (address, replicas, settings_.port, kwargs) == ("auto", 3, 9123, {"replica_cpus": 0.5})
    with pytest.raises(SystemExit):
        cli.main(["serve", "--replicas", "2"])
