"""The FastAPI application: routers, problem documents, limits, auth, metrics, start-up."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI
from fastapi.concurrency import run_in_threadpool
from fastapi.middleware.cors import CORSMiddleware
from fastapi.openapi.utils import get_openapi

from drape import __version__
from drape.runtime.body_store import BodyStore
from drape.runtime.engine import Engine
from drape.runtime.intrinsic import garment_names
from drape.schemas.catalog import BodyMesh, BodyRegistered
from drape.schemas.garments import (
    EncodeFields,
    EncodeRequest,
    EncodeResponse,
    GarmentTemplate,
    KeyframeAnimateRequest,
    KeyframeFields,
    SampleFields,
    SampleRequest,
    SampleResponse,
)
from drape.schemas.layers import LayersAnimateRequest, LayersAnimateResponse
from drape.schemas.outfits import (
    AnimateRequest,
    AnimateResponse,
    FitRequest,
    FitResponse,
    Problem,
    RefineRequest,
    RigRequest,
    RigResponse,
)
from drape.service import catalog, problems
from drape.service.admission import Admission
from drape.service.bodies import stored_body
from drape.service.http import HeadAsGet, require_api_key
from drape.service.metrics import CountRequests, Metrics
from drape.service.notices import WARNINGS_HEADER, WarningsHeader
from drape.service.routers import bodies, garments, health, layers, models, outfits, viewer
from drape.service.routers import catalog as catalog_router
from drape.service.settings import Settings


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    metrics = Metrics()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        def start() -> None:
            catalog.bodies()
            catalog.motions()
            engine = Engine(settings.model_dir, settings.ort_threads, settings.outfit_cache_bytes,
                            observe=metrics.observe_inference, refine_workers=settings.refine_workers,
                            intrinsic_dir=settings.intrinsic_dir, collision_fit=settings.collision_fit)
            engine.warm_up()
            app.state.engine = engine
            app.state.bodies = BodyStore(settings.max_bodies, settings.max_body_store_bytes, settings.body_dir,
                                         check=lambda arrays, name: stored_body(arrays, name, settings))

        await run_in_threadpool(start)
        app.state.admission = Admission(settings.max_active, settings.max_queue, settings.queue_timeout_s,
                                        settings.retry_after_s, metrics.admission, metrics.rejection)
        app.state.ready = True
        yield
        app.state.ready = False
        app.state.bodies.close()
        await run_in_threadpool(app.state.engine.close)

    app = FastAPI(
        title="drape", version=__version__, lifespan=lifespan,
        description="Neural garment animation: outfit rigging (DeePSD) and posed vertex streams; the intrinsic "
                    "garment space of trained garment templates (keyframes -> streams, design samples). "
                    "Errors are RFC 9457 problem documents. Units: metres, +Y up, 24-joint SMPL skeleton.",
    )
    app.state.ready = False
    app.state.settings = settings
    app.state.metrics = metrics
    problems.install(app)
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["*"],
                           allow_headers=["*"], expose_headers=[WARNINGS_HEADER])

    app.add_middleware(WarningsHeader)  # innermost: each request's warnings list, read when its answer starts
    app.add_middleware(HeadAsGet)  # inside CountRequests: HEAD is counted as HEAD
    app.add_middleware(CountRequests, metrics=metrics)  # outside problems.CatchAll: counts its 500s too

    app.include_router(health.router)
    app.include_router(viewer.router)  # the page and its files; the page calls /v1 with the key typed into it
    auth = [Depends(require_api_key)]
    for router in (catalog_router.router, bodies.router, models.router, outfits.router, outfits.refine_router,
                   garments.router, layers.router):
        app.include_router(router, dependencies=auth)

    def openapi() -> dict:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
        comps = schema.setdefault("components", {}).setdefault("schemas", {})
        _drop_default_validation_errors(schema)
        for model in (RigRequest, RigResponse, FitRequest, FitResponse, AnimateRequest, AnimateResponse, RefineRequest, Problem,
                      GarmentTemplate, EncodeRequest, EncodeFields, EncodeResponse, KeyframeAnimateRequest,
                      KeyframeFields, SampleRequest, SampleFields, SampleResponse, BodyMesh, BodyRegistered,
                      LayersAnimateRequest, LayersAnimateResponse):
            js = model.model_json_schema(ref_template="#/components/schemas/{model}")
            comps.update(js.pop("$defs", {}))
            comps[model.__name__] = js
        _garment_name_examples(schema, garment_names(settings.intrinsic_dir))
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
    return app


def _drop_default_validation_errors(schema: dict) -> None:
    """FastAPI declares a 422 (HTTPValidationError, application/json) on every route with a parameter; drape's
    routes read their bodies themselves and their path parameters are plain strings, so that answer never
    occurs (and every 422 drape gives is problem+json, declared by the routes that give it): drop it and its
    schemas."""
    ref = "#/components/schemas/HTTPValidationError"
    for item in schema.get("paths", {}).values():
        for operation in item.values():
            responses = operation.get("responses", {}) if isinstance(operation, dict) else {}
            if responses.get("422", {}).get("content", {}).get("application/json", {}).get("schema", {}).get(
                    "$ref") == ref:
                del responses["422"]
    for name in ("HTTPValidationError", "ValidationError"):
        schema.get("components", {}).get("schemas", {}).pop(name, None)


def _garment_name_examples(schema: dict, names: list[str]) -> None:
    """The served garments' names as the example of every garment route's `name` parameter (the docs page and
    the contract tests then reach a garment)."""
    if not names:
        return
    for path, item in schema.get("paths", {}).items():
        if not path.startswith("/v1/garments/{name}"):
            continue
        for operation in item.values():
            for param in operation.get("parameters", []) if isinstance(operation, dict) else []:
                if param.get("name") == "name" and param.get("in") == "path":
                    param["example"] = names[0]
