"""The API against its own OpenAPI schema (schemathesis, in process), positive and negative cases,
including the schema's examples, which are valid meshes and motions that reach the engine."""

from collections import Counter

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.generation import GenerationMode
from schemathesis.specs.openapi.checks import (
    negative_data_rejection,
    response_schema_conformance,
    status_code_conformance,
)
from svc_env import test_settings

from drape.service.app import create_app

CHECKS = [not_a_server_error, status_code_conformance, response_schema_conformance, negative_data_rejection]
CASES = {"count": 0}
STATUS: Counter = Counter()  # (method, path, status) -> cases
APP = create_app(test_settings())
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)
schema.config.generation.update(modes=[GenerationMode.POSITIVE, GenerationMode.NEGATIVE], max_examples=220)


@pytest.fixture(scope="module", autouse=True)
def started():
    with TestClient(APP):  # the lifespan loads and warms the engine
        yield


@schema.parametrize()
@settings(max_examples=220, deadline=None, suppress_health_check=list(HealthCheck))
def test_api_conforms_to_its_schema(case):
    CASES["count"] += 1
    response = case.call_and_validate(checks=CHECKS)
    STATUS[(case.method.upper(), case.path, response.status_code)] += 1


def test_zz_enough_generated_cases():
    """Runs after the schema tests in this module: >= 1,000 generated cases in the default run, and each
    computing route answered 200 to some of them (they reached the engine, not only the validation); the
    garment routes' `name` example is the served test garment (encode needs its exact vertex count, which
    generated cases do not hit)."""
    print(f"\n{CASES['count']} cases;", ", ".join(f"{m} {p} {s}: {n}" for (m, p, s), n in sorted(STATUS.items())
                                                  if m == "POST"))
    assert CASES["count"] >= 1000, CASES["count"]
    for path in ("/v1/outfits/rig", "/v1/outfits/animate", "/v1/refine", "/v1/garments/{name}/animate",
                 "/v1/garments/{name}/sample"):
        assert STATUS[("POST", path, 200)] >= 1, sorted(STATUS.items())
    assert STATUS[("GET", "/v1/garments/{name}", 200)] >= 1, sorted(STATUS.items())
