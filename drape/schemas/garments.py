"""Requests and answers of the garment routes: the intrinsic garment space (Wang et al. 2019) of trained garment
templates. A latent (Z,) describes a garment's shape independently of the motion; decoded with a frame's motion
window it gives the garment at that frame. Vertices are metres, world space of the frame they belong to;
frames are 0-based indices into the request's motion."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from drape.schemas.outfits import MotionInput, RefineOptions, Vec3

MAX_SAMPLES = 64  # design candidates one sample request may ask for
MAX_SEED = 2**63 - 1
EXAMPLE_LATENT_SIZE = 100  # the paper's latent size: what the examples assume


class GarmentInfo(BaseModel):
    """A served garment template and its models."""

    name: str = Field(description="what the garment routes' {name} takes")
    num_vertices: int = Field(description="N, the template's vertex count: every stream and shape of it is (N, 3)")
    num_faces: int = Field(description="F, the template's triangle count")
    body: str = Field(description="the body preset the template is dressed on and the model was trained with")
    models: list[str] = Field(description="the models of this template: 'intrinsic'; for a layer template "
                                          "(GET /v1/layers) what animates it: 'mgn_inner' or 'deepsd' for "
                                          "an inner one (whichever measured better), 'mgn_outer' for an outer one")
    fps: float | None = Field(None, description="the frame rate of the training motions (intrinsic)")
    window: int | None = Field(None, description="past frames in a motion window, besides the current one "
                                                 "(intrinsic)")
    version: str | None = Field(None, description="the intrinsic model's version")
    latent_size: int | None = Field(None, description="Z, the size of a latent (intrinsic)")


class GarmentList(BaseModel):
    """The served garment templates (GET /v1/garments)."""

    garments: list[GarmentInfo] = Field(description="the intrinsic templates, then the layer templates")


class GarmentTemplate(BaseModel):
    """The template mesh in rest pose on its body: vertices (N, 3) metres, faces (F, 3)."""

    name: str = Field(description="the template's name")
    body: str = Field(description="the body preset the template is dressed on")
    vertices: list[Vec3] = Field(description="(N, 3) rest-pose vertices, metres, +Y up")
    faces: list[list[int]] = Field(description="(F, 3) triangles: 0-based indices into vertices")


class EncodeFields(BaseModel):
    """A keyframe shape: the garment's vertices (N, 3) m, world space at `frame` of the motion."""

    model_config = ConfigDict(extra="forbid", strict=True)
    vertices: list[Vec3] = Field(min_length=1, description="(N, 3) metres, N the template's vertex count, "
                                                           "in the template's vertex order")
    frame: int = Field(ge=0, description="0-based index of the frame the shape belongs to")


class EncodeRequest(EncodeFields):
    """A keyframe shape and the motion it belongs to (the frames up to `frame` give its motion window)."""

    motion: MotionInput = Field(description="the body's motion; `frame` indexes it")


class EncodeResponse(BaseModel):
    """The keyframe's latent (Z,)."""

    latent: list[float] = Field(description="(Z,) the shape's latent, Z the template's latent_size (GET "
                                            "/v1/garments): a keyframe's `latent` in animate")


class Keyframe(BaseModel):
    """A keyframe: the garment's shape at `frame`, as vertices (N, 3) m in world space (encoded with the motion up
    to that frame) or as a latent (Z,) (from encode or sample). Exactly one of the two."""

    model_config = ConfigDict(extra="forbid", strict=True)
    frame: int = Field(ge=0, description="0-based index of the motion frame the keyframe belongs to")
    vertices: list[Vec3] | None = Field(None, description="(N, 3) the garment's shape, metres, world space at "
                                        "`frame`, in the template's vertex order")
    latent: list[float] | None = Field(None, description="(Z,) a latent from encode or sample")


class KeyframeFields(BaseModel):
    """Keyframes and how to meet them: a keyframe animate request without its motion (the `request` field of the
    multipart form, beside its motion_file)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    keyframes: list[Keyframe] = Field(min_length=1, description="at least one; one keyframe per frame")
    match_keyframes: bool = Field(True, description="keyframes given as vertices are met exactly at their frames: "
                                  "what decoding their latents misses is added back, fading with the distance "
                                  "from them (false: the decoded latents alone); refine runs after, and moves "
                                  "what of a keyframe lies inside the body")
    refine: bool | RefineOptions = Field(False, description="collision refinement post step against the "
                                                            "garment's body: true or options; it runs after "
                                                            "match_keyframes")


EXAMPLE_KEYFRAMES: list[Any] = [{"frame": 0, "latent": [0.0] * EXAMPLE_LATENT_SIZE},
                                 {"frame": 2, "latent": [0.5] * EXAMPLE_LATENT_SIZE}]
EXAMPLE_MOTION: dict[str, Any] = {"poses": [[0.0] * 72, [0.05] * 72, [0.1] * 72], "translation": [[0, 0, 0]] * 3,
                                  "fps": 30.0}


class KeyframeAnimateRequest(KeyframeFields):
    """Keyframes and a motion -> the garment's stream: latents linearly interpolated between the keyframes (held
    before the first and after the last), each frame decoded with its motion window."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"motion": EXAMPLE_MOTION, "keyframes": EXAMPLE_KEYFRAMES},
        {"motion": EXAMPLE_MOTION, "keyframes": EXAMPLE_KEYFRAMES[1:], "refine": True}]})
    motion: MotionInput = Field(description="the body's motion: the stream has its T frames")


class SampleFields(BaseModel):
    """How many candidates, the seed and the frame: a sample request without its motion (the `request` field of
    the multipart form, beside its motion_file)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    count: int = Field(ge=1, le=MAX_SAMPLES, description="design candidates to draw")
    seed: int = Field(0, ge=0, le=MAX_SEED, description="the random generator's seed: same seed, same latents")
    frame: int = Field(0, ge=0, description="0-based frame of the motion the shapes are decoded at")


class SampleRequest(SampleFields):
    """Design candidates: latents drawn from the training latents' statistics (mean + std * standard normal),
    decoded at `frame` of the motion."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"count": 4, "seed": 7, "motion": EXAMPLE_MOTION, "frame": 2},
        {"count": 2, "seed": 1, "motion": {"clip": "kick"}, "frame": 10}]})
    motion: MotionInput = Field(description="the body's motion; `frame` indexes it")


class SampleResponse(BaseModel):
    """latents (count, Z) and their shapes (count, N, 3) metres, world space at the frame."""

    latents: list[list[float]] = Field(description="(count, Z) the drawn latents")
    vertices: list[list[Vec3]] = Field(description="(count, N, 3) their shapes, metres, world space at `frame`")
