"""The loaded models: versions, checksums, I/O specs and evaluation tables."""

from __future__ import annotations

from fastapi import APIRouter, Path, Request

from drape.schemas.models import ModelInfo, ModelList
from drape.service.errors import NotFound
from drape.service.http import engine_of
from drape.service.problems import problem_responses

router = APIRouter(prefix="/v1", tags=["models"], responses=problem_responses(401))


def _info(request: Request) -> list[ModelInfo]:
    engine = engine_of(request)
    m = engine.model.manifest
    models = [ModelInfo(name=m["name"], version=m["version"], trained=m["trained"], files=m["files"],
                        evaluation=m.get("evaluation"))]
    for garment in engine.garments:  # the intrinsic spaces, one per garment template: intrinsic-<template>
        g = garment.manifest
        onnx = {k: f for k, f in g["files"].items() if str(f["file"]).endswith(".onnx")}
        models.append(ModelInfo(name=f"intrinsic-{garment.name}", version=g["version"], trained="training" in g,
                                files=onnx, evaluation=g.get("evaluation")))
    return models


@router.get("/models", response_model=ModelList)
def list_models(request: Request) -> ModelList:
    """Every loaded model with version, sha256, inputs/outputs (-1 = dynamic axis) and evaluation."""
    return ModelList(models=_info(request))


@router.get("/models/{name}", response_model=ModelInfo, responses=problem_responses(404))
def get_model(request: Request, name: str = Path(description="a model's name (GET /v1/models): 'deepsd' or "
                                                            "'intrinsic-<template>'")) -> ModelInfo:
    """One loaded model by name."""
    for info in _info(request):
        if info.name == name:
            return info
    raise NotFound(f"no model named {name!r}", "name")
