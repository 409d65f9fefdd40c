"""The embedded body presets and motion clips."""

from __future__ import annotations

from fastapi import APIRouter

from drape.schemas.catalog import BodyList, MotionList
from drape.service import catalog

router = APIRouter(prefix="/v1", tags=["catalog"])


@router.get("/bodies", response_model=BodyList)
def list_bodies() -> BodyList:
    """Body presets with their 24-joint skeleton (SMPL order) and mesh sizes."""
    return catalog.bodies()


@router.get("/motions", response_model=MotionList)
def list_motions() -> MotionList:
    """Embedded motion clips: name, frames, fps."""
    return catalog.motions()
