"""The OpenAPI schema documents what it declares (what API users read on /docs): every operation says what it
does, every field of every component schema says what it means, every multipart form field and every binary
body (npz, frame stream, PC2, GLB) says what it holds, and every error answer is declared as the problem+json it
is. Built from create_app(...).openapi(): no server, no models loaded."""

import pytest

from drape.service.app import create_app
from drape.service.settings import Settings

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def schema() -> dict:
    return create_app(Settings()).openapi()


def operations(schema: dict):
    for path, item in schema["paths"].items():
        for method, op in item.items():
            yield f"{method.upper()} {path}", op


def test_every_operation_has_a_summary_and_a_description(schema):
    missing = [name for name, op in operations(schema) if not op.get("summary") or not op.get("description")]
    assert not missing, missing


def test_every_component_schema_and_field_is_described(schema):
    undescribed = []
    for name, component in schema["components"]["schemas"].items():
        if not component.get("description"):
            undescribed.append(name)
        undescribed += [f"{name}.{field}" for field, prop in component.get("properties", {}).items()
                        if not prop.get("description")]
    assert not undescribed, f"{len(undescribed)} undescribed: {undescribed}"


def test_every_parameter_form_field_and_binary_body_is_described(schema):
    undescribed = []
    for name, op in operations(schema):
        undescribed += [f"{name} parameter {p['name']}" for p in op.get("parameters", []) if not p.get("description")]
        for kind, content in op.get("requestBody", {}).get("content", {}).items():
            body = content["schema"]
            undescribed += [f"{name} {kind} field {field}" for field, prop in body.get("properties", {}).items()
                            if not prop.get("description")]
            if body.get("format") == "binary" and not body.get("description"):
                undescribed.append(f"{name} request {kind}")
        for status, response in op["responses"].items():
            for kind, content in response.get("content", {}).items():
                if content["schema"].get("format") == "binary" and not content["schema"].get("description"):
                    undescribed.append(f"{name} {status} {kind}")
    assert not undescribed, undescribed


def test_error_answers_are_declared_as_the_problems_they_are(schema):
    """Every declared 4xx/5xx is problem+json (not FastAPI's default 422 HTTPValidationError, which drape never
    answers), a 503 carries Retry-After, and every /v1 route declares the 401 of the API key."""
    wrong = []
    for name, op in operations(schema):
        for status, response in op["responses"].items():
            if int(status) < 400 or name == "GET /readyz":  # readyz's 503 is its Health document
                continue
            if set(response.get("content", {})) != {PROBLEM}:
                wrong.append(f"{name} {status}: {sorted(response.get('content', {}))}")
            if status == "503" and "Retry-After" not in response.get("headers", {}):
                wrong.append(f"{name} 503 without Retry-After")
        if name.split()[1].startswith("/v1/") and "401" not in op["responses"]:
            wrong.append(f"{name} declares no 401")
    assert not wrong, wrong
    assert "HTTPValidationError" not in schema["components"]["schemas"]
