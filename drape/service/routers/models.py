"""The loaded models: versions, checksums, I/O specs and evaluation tables."""

from __future__ import annotations

from fastapi import APIRouter, Request

from drape.schemas.models import ModelInfo, ModelList
from drape.service.errors import NotFound
from drape.service.http import engine_of
from drape.service.problems import problem_responses

router = APIRouter(prefix="/v1", tags=["models"], responses=problem_responses(401))


def _info(request: Request) -> list[ModelInfo]:
    m = engine_of(request).model.manifest
    return [ModelInfo(name=m["name"], version=m["version"], trained=m["trained"], files=m["files"],
                      evaluation=m.get("evaluation"))]


@router.get("/models", response_model=ModelList)
def list_models(request: Request) -> ModelList:
    """Every loaded model with version, sha256, inputs/outputs (-1 = dynamic axis) and evaluation."""
    return ModelList(models=_info(request))


@router.get("/models/{name}", response_model=ModelInfo, responses=problem_responses(404))
def get_model(name: str, request: Request) -> ModelInfo:
    """One loaded model by name."""
    for info in _info(request):
        if info.name == name:
            return info
    raise NotFound(f"no model named {name!r}", "name")
