"""Requests and answers of the layer routes: an inner and an outer garment template worn together, animated
along a motion. Vertices are metres, world space; thickness is the inner garment's (H_in), metres."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from drape.schemas.outfits import MotionInput, RefineOptions, Vec3


class LayerInfo(BaseModel):
    """A served combination of two garment templates (each served by GET /v1/garments/{name})."""

    inner: str = Field(description="the inner garment template's name (GET /v1/garments/{name})")
    outer: str = Field(description="the outer garment template's name, worn over the inner")
    body: str = Field(description="the body preset both templates are dressed on")
    thickness: list[float] = Field(description="[min, max]: the inner thicknesses served, metres")
    model: str = Field(description="what poses the layers: '<inner_model>+<outer_model>', or the one name when "
                                   "both are the same (then, with refine, the post step between layers)")
    inner_model: str = Field(description="what poses the inner layer: 'mgn_inner' (MGN's inner-layer network of "
                                         "the template) or 'deepsd' (DeePSD's rig of the layer alone)")
    outer_model: str = Field(description="what poses the outer layer: 'mgn_outer' (MGN's outer-layer network of "
                                         "the combination: a Transformer over the motion reading the inner layer "
                                         "and the thickness) or 'deepsd' (DeePSD's rig of the layer alone)")


class LayerList(BaseModel):
    """The served combinations (GET /v1/layers)."""

    layers: list[LayerInfo] = Field(description="every combination POST /v1/layers/animate takes")


class LayersFields(BaseModel):
    """Two templates worn together (a combination of GET /v1/layers) and the inner's thickness: a layers animate
    request without its motion (the `request` field of the multipart form, beside its motion_file)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    inner: str = Field(max_length=128, description="the inner template (GET /v1/layers)")
    outer: str = Field(max_length=128, description="the outer template")
    thickness: float = Field(0.006, description="the inner garment's thickness H_in, metres, within the "
                                                "combination's range")
    refine: bool | RefineOptions = Field(False, description="the post step: both layers out of the body, the "
                                                            "outer kept thickness + 1 mm outside the inner")


class LayersAnimateRequest(LayersFields):
    """Two templates worn together (a combination of GET /v1/layers), the inner's thickness, a motion."""

    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"examples": [
        {"inner": "tshirt", "outer": "jacket", "thickness": 0.006, "motion": {"clip": "walk"}, "refine": True}]})
    motion: MotionInput = Field(description="the body's motion: both streams have its T frames")


class LayersAnimateResponse(BaseModel):
    """Both layers' frames: inner_vertices (T, Ni, 3), outer_vertices (T, No, 3) metres, and their faces."""

    inner: str = Field(description="the inner template's name")
    outer: str = Field(description="the outer template's name")
    fps: float = Field(description="frames per second of both streams")
    inner_vertices: list[list[Vec3]] = Field(description="(T, Ni, 3) the inner layer per frame, metres, world space")
    inner_faces: list[list[int]] = Field(description="(Fi, 3) the inner layer's triangles, 0-based indices")
    outer_vertices: list[list[Vec3]] = Field(description="(T, No, 3) the outer layer per frame, metres, world space")
    outer_faces: list[list[int]] = Field(description="(Fo, 3) the outer layer's triangles, 0-based indices")
