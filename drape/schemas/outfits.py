"""Requests and answers of the outfit routes (rig, animate), and the problem document."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Tri = Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=3, max_length=3)]


class Mesh(BaseModel):
    """A triangle mesh in the body's rest pose: vertices (N, 3) metres, faces (F, 3) indices into vertices."""

    model_config = ConfigDict(extra="forbid", strict=True)
    vertices: list[Vec3] = Field(min_length=3)
    faces: list[Tri] = Field(min_length=1)


EXAMPLE_MESH: dict[str, Any] = {"vertices": [[0.0, 1.0, 0.2], [0.1, 1.0, 0.2], [0.0, 1.1, 0.2], [0.1, 1.1, 0.25]],
                "faces": [[0, 1, 2], [1, 3, 2]]}


INFLUENCES_HELP = ("skin influences per vertex of the served rig: 4 (what three.js and most engines play) or 8; "
                   "the blend shapes are refit for them")


FIT_HELP = ("fit the mesh onto the body first, as POST /v1/outfits/fit does with its units and up axis inferred; "
            "the answer then carries the fitted vertices")


class FitRequest(Mesh):
    """A garment made for another body, in any units and up axis, to be put on a drape body at rest."""

    model_config = ConfigDict(json_schema_extra={"examples": [{**EXAMPLE_MESH, "body": "neutral", "units": "m"}]})

    body: str = Field("neutral", description="body to fit the garment onto: a preset (GET /v1/bodies) or a body_id (POST /v1/bodies)")
    units: Literal["m", "cm", "mm"] | None = Field(None, description="the mesh's units (default: inferred from "
                                                   "its size, and said so in the report)")
    up: Literal["y", "z"] | None = Field(None, description="the mesh's up axis (default: inferred: a garment is "
                                         "thinnest front to back)")
    pose: Literal["t", "a"] | Annotated[list[Vec3], Field(min_length=24, max_length=24)] = Field(
        "t", description="the pose the garment was made in: 't' (T-pose), 'a' (arms 45 degrees down) or (24, 3) "
        "axis-angle radians; un-posed with the body's own inverse skinning")


class FitReport(BaseModel):
    units: str = Field(description="m, cm or mm: as given or inferred")
    units_inferred: bool
    up: str = Field(description="y or z: as given or inferred")
    up_inferred: bool
    pose: str = Field(description="t, a or given")
    placement_score_mm: float = Field(description="how closely the placed garment hugs the body (mean distance, "
                                      "capped at 10 cm, inside counted thrice), mm")
    inside_before: float = Field(description="share of the vertices inside the body at rest before the push-out")
    inside_after: float = Field(description="share of the vertices inside the body at rest after it")
    max_move_mm: float = Field(description="largest move of the push-out, mm")
    mean_move_mm: float = Field(description="mean move of the push-out, mm")
    max_stretch_mm: float = Field(description="largest edge lengthening by the push-out, mm")


class FitResponse(BaseModel):
    """The garment fitted onto the body at rest: vertices (N, 3) metres, Y-up; the faces as given; the
    similarity (4, 4) applied before the push-out (units, up axis, facing, translation); what was done."""

    vertices: list[Vec3]
    faces: list[list[int]]
    transform: list[list[float]] = Field(description="(4, 4), row-major, acting on column vectors")
    report: FitReport


class RigRequest(Mesh):
    """A template outfit (strict types: no string-to-number coercion)."""

    model_config = ConfigDict(json_schema_extra={"examples": [{**EXAMPLE_MESH, "body": "neutral"}]})

    body: str = Field("neutral", description="body the outfit is dressed on: a preset (GET /v1/bodies) or a body_id (POST /v1/bodies)")
    influences: Literal[4, 8] = Field(4, description=INFLUENCES_HELP)
    fit: bool = Field(False, description=FIT_HELP)


class Skeleton(BaseModel):
    joint_names: list[str]
    parents: list[int]
    rest_joints: list[list[float]] = Field(description="(24, 3) metres")


class DistanceMm(BaseModel):
    min: float
    median: float
    max: float


class RigDiagnostics(BaseModel):
    """Where the mesh sits on the body at rest: read the warnings before animating."""

    inside_share: float = Field(description="share of the vertices inside the body at rest")
    distance_mm: DistanceMm = Field(description="distance of the vertices to the body surface, mm")
    bbox: dict[str, list[list[float]]] = Field(description="garment and body bounding boxes [[min], [max]], m")
    warnings: list[str] = Field(description="plain sentences: misplaced, Z-up, wrong units")


class RigResponse(BaseModel):
    """What an engine needs to pose the outfit: W (N, 24), D (P, N, 3) metres, the skeleton, and where the
    mesh sits on the body (diagnostics)."""

    outfit_id: str = Field(description="content hash of the mesh + body + model version; reuse with animate")
    num_vertices: int
    skinning_weights: list[list[float]]
    blend_shapes: list[list[list[float]]]
    skeleton: Skeleton
    diagnostics: RigDiagnostics
    fit: FitResponse | None = Field(None, description="with fit: true, the fitted mesh the rig belongs to")
    parts: list[MeshPart] | None = Field(None, description="an uploaded OBJ's objects (or groups) in the file's "
                                         "order, as vertex ranges of the rig's arrays")


class MeshPart(BaseModel):
    name: str
    start: int = Field(description="first vertex")
    stop: int = Field(description="one past the last vertex")


class MotionInput(BaseModel):
    """Either an embedded clip name, or poses (T, 24, 3) / (T, 72) axis-angle radians + translation (T, 3) m."""

    model_config = ConfigDict(extra="forbid", strict=True)
    clip: str | None = Field(None, description="name of an embedded clip (GET /v1/motions)")
    poses: list[list[float]] | list[list[Vec3]] | None = None
    translation: list[Vec3] | None = None
    fps: float = Field(30.0, gt=0, le=1000, allow_inf_nan=False)


class RefineOptions(BaseModel):
    """Collision refinement: push vertices out of the body by eps (m), keeping the local shape."""

    model_config = ConfigDict(extra="forbid", strict=True)
    eps: float = Field(0.003, gt=0, le=0.05, allow_inf_nan=False, description="distance kept from the body surface, metres")
    max_iterations: int = Field(3, ge=1, le=20, description="fast-path iterations before the progressive pass")
    relief_iterations: int = Field(10, ge=0, le=50, description="rounds of the stretch relief pass after the "
                                   "solve, which slides stretched cloth along the body (0: none, 15-20% less "
                                   "time, more edges stretched by over 1 cm; see docs/refine.md)")


class AnimateRequest(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"examples": [
        {"outfit": EXAMPLE_MESH, "motion": {"clip": "kick"}},
        {"outfit": EXAMPLE_MESH, "motion": {"poses": [[0.0] * 72, [0.1] * 72], "translation": [[0, 0, 0]] * 2,
                                            "fps": 24.0}, "refine": True}]})
    outfit: Mesh | None = None
    outfit_id: str | None = Field(None, max_length=128)
    motion: MotionInput
    body: str | None = Field(None, description="body preset; defaults to the rigged outfit's, else neutral")
    influences: Literal[4, 8] | None = Field(None, description=INFLUENCES_HELP + " (default 4; with outfit_id: "
                                             "the rigged outfit's)")
    refine: bool | RefineOptions = Field(False, description="collision refinement post step: true or options")
    fit: bool = Field(False, description=FIT_HELP.split(";")[0] + " (with outfit, not outfit_id)")


class InnerLayer(BaseModel):
    """The garment worn under the refined one: its stream (T, Ni, 3) m over the same frames, its faces, and its
    thickness (m). The refined garment is pushed out of the body and then kept thickness + 1 mm outside this
    layer (which is itself first refined against the body, as /v1/refine would refine it alone)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    vertices: list[list[Vec3]] = Field(min_length=1)
    faces: list[Tri] = Field(min_length=1)
    thickness: float = Field(0.006, gt=0, le=0.05, allow_inf_nan=False, description="the inner layer's thickness H_in, metres")


class RefineRequest(BaseModel):
    """A garment stream (T, N, 3) m with its faces, the body motion that goes with it, the body preset."""

    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"examples": [
        {"vertices": [EXAMPLE_MESH["vertices"]] * 2, "faces": EXAMPLE_MESH["faces"],
         "motion": {"poses": [[0.0] * 72, [0.2] * 72]}, "options": {"relief_iterations": 0}}]})
    vertices: list[list[Vec3]] = Field(min_length=1)
    faces: list[Tri] = Field(min_length=1)
    motion: MotionInput
    body: str = "neutral"
    options: RefineOptions | None = Field(None, description="defaults: eps 3 mm, 3 iterations, 10 relief rounds")
    inner: InnerLayer | None = Field(None, description="a garment under this one: the stream is also pushed out "
                                     "of it (outer-through-inner removed)")


class AnimateResponse(BaseModel):
    """Posed vertices (T, N, 3) metres, the faces (F, 3), frames per second."""

    outfit_id: str
    fps: float
    vertices: list[list[Vec3]]
    faces: list[list[int]]


class Problem(BaseModel):
    """RFC 9457 problem details."""

    type: str
    title: str
    status: int
    detail: str
