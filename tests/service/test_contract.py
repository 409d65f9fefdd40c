"""The API against its own OpenAPI schema (schemathesis, in process), positive and negative cases."""

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
APP = create_app(test_settings())
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)
schema.config.generation.update(modes=[GenerationMode.POSITIVE, GenerationMode.NEGATIVE], max_examples=120)


@pytest.fixture(scope="module", autouse=True)
def started():
    with TestClient(APP):  # the lifespan loads and warms the engine
        yield


@schema.parametrize()
@settings(max_examples=120, deadline=None, suppress_health_check=list(HealthCheck))
def test_api_conforms_to_its_schema(case):
    CASES["count"] += 1
    case.call_and_validate(checks=CHECKS)


def test_zz_enough_generated_cases():
    """Runs after the schema tests in this module: >= 500 generated cases in the default run."""
    assert CASES["count"] >= 500, CASES["count"]
