"""Liveness, readiness and metrics: async routes that run on the event loop and never wait for the
thread pool, so they answer while every computing slot is busy."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse

from drape.schemas.catalog import Health

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness probe")
async def healthz() -> Health:
    """The process is alive."""
    return Health(status="ok")


@router.get("/readyz", response_model=Health, summary="Readiness probe",
            responses={503: {"model": Health, "description": "not ready yet: {\"status\": \"starting\"}"}})
async def readyz(request: Request) -> Health | JSONResponse:
    """Models loaded and warmed up, assets loaded; 503 until then."""
    if not getattr(request.app.state, "ready", False):
        return JSONResponse(status_code=503, content={"status": "starting"})
    return Health(status="ready")


@router.get("/metrics", response_class=Response, summary="Prometheus metrics",
            responses={200: {"description": "Prometheus text exposition format 0.0.4",
                             "content": {"text/plain": {"schema": {"type": "string"}}}}})
async def metrics(request: Request) -> Response:
    """Prometheus text: requests and latencies per route, inference time, frames and vertices served."""
    return Response(request.app.state.metrics.render(), media_type="text/plain; version=0.0.4")
