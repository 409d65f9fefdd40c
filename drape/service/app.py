"""The FastAPI application."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware

from drape import __version__
from drape.service import catalog
from drape.service.routers import catalog as catalog_router
from drape.service.routers import health
from drape.service.settings import Settings


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        catalog.bodies()  # load and validate the embedded assets before declaring ready
        catalog.motions()
        app.state.ready = True
        yield

    app = FastAPI(title="drape", version=__version__, lifespan=lifespan,
                  description="Neural garment animation: outfit rigging, posed vertex streams, refinement.")
    app.state.ready = False
    app.state.settings = settings
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["*"], allow_headers=["*"])
    app.include_router(health.router)
    app.include_router(catalog_router.router)
    return app
