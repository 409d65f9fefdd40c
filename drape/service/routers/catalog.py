"""The embedded body presets and motion clips."""

from __future__ import annotations

from fastapi import APIRouter, Request

from drape.schemas.catalog import BodyList, MotionList
from drape.service import catalog
from drape.service.problems import problem_responses

router = APIRouter(prefix="/v1", tags=["catalog"], responses=problem_responses(401))


@router.get("/bodies", response_model=BodyList)
def list_bodies(request: Request) -> BodyList:
    """Body presets, then the user bodies registered (POST /v1/bodies), with their 24-joint skeleton (SMPL
    order) and mesh sizes."""
    store = request.app.state.bodies
    users = [catalog.body_info(b, preset=False) for b in (store.get(n) for n in store.names()) if b is not None]
    return BodyList(bodies=[*catalog.bodies().bodies, *users])


@router.get("/motions", response_model=MotionList)
def list_motions() -> MotionList:
    """Embedded motion clips: name, frames, fps."""
    return catalog.motions()
