"""The loaded models: versions, checksums, I/O specs and evaluation tables."""

from __future__ import annotations

from fastapi import APIRouter, Path, Request

from drape.runtime.engine import Engine
from drape.runtime.layers import InnerModel, OuterModel
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
    for name, network in _layer_networks(engine):
        lm = network.manifest
        onnx = {k: f for k, f in lm["files"].items() if str(f["file"]).endswith(".onnx")}
        models.append(ModelInfo(name=name, version=lm["version"], trained="training" in lm, files=onnx,
                                evaluation=lm.get("evaluation")))
    return models


def _layer_networks(engine: Engine) -> list[tuple[str, InnerModel | OuterModel]]:
    """The layer networks served now (GET /v1/layers), once each: 'mgn_inner-<inner>' per inner template and
    'mgn_outer-<inner>_<outer>' per combination (an outer network reads its inner network's keys); a layer that
    DeePSD's rig poses has none."""
    found: dict[str, InnerModel | OuterModel] = {}
    for c in engine.layers.combinations():
        if c.inner.network is not None:
            found.setdefault(f"{c.inner.network.name}-{c.inner.name}", c.inner.network)
        if c.outer.network is not None:
            found.setdefault(f"{c.outer.network.name}-{c.inner.name}_{c.outer.name}", c.outer.network)
    return list(found.items())


@router.get("/models", response_model=ModelList)
def list_models(request: Request) -> ModelList:
    """Every loaded model with version, sha256, inputs/outputs (-1 = dynamic axis) and evaluation."""
    return ModelList(models=_info(request))


@router.get("/models/{name}", response_model=ModelInfo, responses=problem_responses(404))
def get_model(request: Request, name: str = Path(description="a model's name (GET /v1/models): 'deepsd', "
                                                            "'intrinsic-<template>', 'mgn_inner-<inner>' or "
                                                            "'mgn_outer-<inner>_<outer>'")) -> ModelInfo:
    """One loaded model by name."""
    for info in _info(request):
        if info.name == name:
            return info
    raise NotFound(f"no model named {name!r}", "name")
