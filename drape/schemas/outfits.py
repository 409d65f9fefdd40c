"""Requests and answers of the outfit routes (rig, animate), and the problem document."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Tri = Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=3, max_length=3)]


class Mesh(BaseModel):
    """A triangle mesh in the body's rest pose: vertices (N, 3) metres, faces (F, 3) indices into vertices."""

    model_config = ConfigDict(extra="forbid", strict=True)
    vertices: list[Vec3] = Field(min_length=3, description="(N, 3) vertex positions, metres, +Y up, on the body "
                                 "at rest (N >= 3; with fit: true, any units, up axis and placement: fitted first)")
    faces: list[Tri] = Field(min_length=1, description="(F, 3) triangles: 0-based indices into vertices (F >= 1)")


EXAMPLE_MESH: dict[str, Any] = {"vertices": [[0.0, 1.0, 0.2], [0.1, 1.0, 0.2], [0.0, 1.1, 0.2], [0.1, 1.1, 0.25]],
                "faces": [[0, 1, 2], [1, 3, 2]]}


INFLUENCES_HELP = ("skin influences per vertex of the served rig: 4 (what three.js and most engines play) or 8; "
                   "the blend shapes are refit for them")


FIT_HELP = ("fit the mesh onto the body first, as POST /v1/outfits/fit does with its units and up axis inferred; "
            "the answer then carries the fitted vertices")


class FitRequest(Mesh):
    """A garment made for another body, in any units and up axis, to be put on a drape body at rest."""

    model_config = ConfigDict(json_schema_extra={"examples": [{**EXAMPLE_MESH, "body": "neutral", "units": "m"}]})

    vertices: list[Vec3] = Field(min_length=3, description="(N, 3) vertex positions in the mesh's own units and "
                                 "up axis (see units, up), placed anywhere (N >= 3)")
    body: str = Field("neutral", description="body to fit the garment onto: a preset (GET /v1/bodies) or a body_id (POST /v1/bodies)")
    units: Literal["m", "cm", "mm"] | None = Field(None, description="the mesh's units (default: inferred from "
                                                   "its size, and said so in the report)")
    up: Literal["y", "z"] | None = Field(None, description="the mesh's up axis (default: inferred: a garment is "
                                         "thinnest front to back)")
    pose: Literal["t", "a"] | Annotated[list[Vec3], Field(min_length=24, max_length=24)] = Field(
        "t", description="the pose the garment was made in: 't' (T-pose), 'a' (arms 45 degrees down) or (24, 3) "
        "axis-angle radians; un-posed with the body's own inverse skinning")


class FitReport(BaseModel):
    """What the fit did: the units and up axis it used, the pose it un-posed, and the push-out out of the body."""

    units: str = Field(description="m, cm or mm: as given or inferred")
    units_inferred: bool = Field(description="true when units was not given and was inferred from the mesh's size")
    up: str = Field(description="y or z: as given or inferred")
    up_inferred: bool = Field(description="true when up was not given and was inferred from the mesh's shape")
    pose: str = Field(description="t, a or given (a (24, 3) axis-angle pose was given)")
    placement_score_mm: float = Field(description="how closely the placed garment hugs the body (mean distance, "
                                      "capped at 10 cm, inside counted thrice), mm")
    inside_before: float = Field(description="share of the vertices inside the body at rest before the push-out")
    inside_after: float = Field(description="share of the vertices inside the body at rest after it")
    max_move_mm: float = Field(description="largest move of the push-out, mm")
    mean_move_mm: float = Field(description="mean move of the push-out, mm")
    max_stretch_mm: float = Field(description="largest edge lengthening by the push-out, mm")
    warnings: list[str] = Field(default_factory=list, description="sentences: units or up given against what the "
                                "mesh's size or shape says (e.g. units cm on a mesh 0.7 units across)")


class FitResponse(BaseModel):
    """The garment fitted onto the body at rest: vertices (N, 3) metres, Y-up; the faces as given; the
    similarity (4, 4) applied before the push-out (units, up axis, facing, translation); what was done."""

    vertices: list[Vec3] = Field(description="(N, 3) the fitted vertices, metres, +Y up, on the body at rest, in "
                                 "the order given")
    faces: list[list[int]] = Field(description="(F, 3) the faces as given")
    transform: list[list[float]] = Field(description="(4, 4), row-major, acting on column vectors")
    report: FitReport = Field(description="what was inferred and done")


class RigRequest(Mesh):
    """A template outfit (strict types: no string-to-number coercion)."""

    model_config = ConfigDict(json_schema_extra={"examples": [{**EXAMPLE_MESH, "body": "neutral"}]})

    body: str = Field("neutral", description="body the outfit is dressed on: a preset (GET /v1/bodies) or a body_id (POST /v1/bodies)")
    influences: Literal[4, 8] = Field(4, description=INFLUENCES_HELP)
    fit: bool = Field(False, description=FIT_HELP)


class Skeleton(BaseModel):
    """The body's 24-joint skeleton the rig is bound to (SMPL order)."""

    joint_names: list[str] = Field(description="24 joints in SMPL order")
    parents: list[int] = Field(description="(24,) parent index per joint, -1 for the root")
    rest_joints: list[list[float]] = Field(description="(24, 3) metres")


class DistanceMm(BaseModel):
    """Statistics of the unsigned distance of the garment's vertices to the body surface, millimetres."""

    min: float = Field(description="smallest distance, mm")
    median: float = Field(description="median distance, mm")
    max: float = Field(description="largest distance, mm")


class RigDiagnostics(BaseModel):
    """Where the mesh sits on the body at rest: read the warnings before animating."""

    inside_share: float = Field(description="share of the vertices inside the body at rest")
    distance_mm: DistanceMm = Field(description="distance of the vertices to the body surface, mm")
    bbox: dict[str, list[list[float]]] = Field(description="'garment' and 'body' bounding boxes, each [[min x, y, "
                                               "z], [max x, y, z]], metres")
    warnings: list[str] = Field(description="plain sentences: misplaced, Z-up, wrong units")


class RigResponse(BaseModel):
    """What an engine needs to pose the outfit: W (N, 24), D (P, N, 3) metres, the skeleton, and where the
    mesh sits on the body (diagnostics)."""

    outfit_id: str = Field(description="content hash of the mesh + body + model version; reuse with animate")
    num_vertices: int = Field(description="N, the outfit's vertex count")
    skinning_weights: list[list[float]] = Field(description="W (N, 24): per vertex, a weight per joint (SMPL "
                                                "order), rows summing to 1, at most `influences` non-zero")
    blend_shapes: list[list[list[float]]] = Field(description="D (P, N, 3) pose-space blend shapes, metres: "
                                                  "offsets in rest pose weighted by the model's P pose keys")
    skeleton: Skeleton = Field(description="the body's skeleton the weights refer to")
    diagnostics: RigDiagnostics = Field(description="where the mesh sits on the body at rest")
    fit: FitResponse | None = Field(None, description="with fit: true, the fitted mesh the rig belongs to")
    parts: list[MeshPart] | None = Field(None, description="an uploaded OBJ's objects (or groups) in the file's "
                                         "order, as vertex ranges of the rig's arrays")


class MeshPart(BaseModel):
    """A named object (or group) of an uploaded mesh file: a range of the outfit's vertices."""

    name: str = Field(description="the object's (or group's) name in the file")
    start: int = Field(description="first vertex")
    stop: int = Field(description="one past the last vertex")


class MotionInput(BaseModel):
    """Either an embedded clip name, or poses (T, 24, 3) / (T, 72) axis-angle radians + translation (T, 3) m."""

    model_config = ConfigDict(extra="forbid", strict=True)
    clip: str | None = Field(None, description="name of an embedded clip (GET /v1/motions)")
    poses: list[list[float]] | list[list[Vec3]] | None = Field(None, description=(
        "(T, 24, 3) or (T, 72) axis-angle radians, local joint rotations relative to the rest pose in SMPL joint "
        "order; (T, 156) SMPL-H rows are taken as their first 72 values. Exactly one of clip and poses"))
    translation: list[Vec3] | None = Field(None, description="(T, 3) root translation per frame, metres (default: "
                                           "zeros); ignored with clip")
    fps: float = Field(30.0, gt=0, le=1000, allow_inf_nan=False, description="frames per second of the poses "
                       "(ignored with clip: a clip plays at its own rate, GET /v1/motions)")


class RefineOptions(BaseModel):
    """Collision refinement: push vertices out of the body by eps (m), keeping the local shape."""

    model_config = ConfigDict(extra="forbid", strict=True)
    eps: float = Field(0.003, gt=0, le=0.05, allow_inf_nan=False, description="distance kept from the body surface, metres")
    max_iterations: int = Field(3, ge=1, le=20, description="fast-path iterations before the progressive pass")
    relief_iterations: int = Field(10, ge=0, le=50, description="rounds of the stretch relief pass after the "
                                   "solve, which slides stretched cloth along the body (0: none, 15-20% less "
                                   "time, more edges stretched by over 1 cm; see docs/refine.md)")


class AnimateRequest(BaseModel):
    """An outfit (a mesh, rigged on the way, or the outfit_id of one rigged before) and a motion -> its posed
    stream (T, N, 3) metres."""

    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"examples": [
        {"outfit": EXAMPLE_MESH, "motion": {"clip": "kick"}},
        {"outfit": EXAMPLE_MESH, "motion": {"poses": [[0.0] * 72, [0.1] * 72], "translation": [[0, 0, 0]] * 2,
                                            "fps": 24.0}, "refine": True}]})
    outfit: Mesh | None = Field(None, description="the outfit mesh on the body at rest (rigged, and cached, on the "
                                "way). Exactly one of outfit and outfit_id")
    outfit_id: str | None = Field(None, max_length=128, description="from POST /v1/outfits/rig (or an earlier "
                                  "animate answer); 404 once it has left the cache")
    motion: MotionInput = Field(description="the body's motion: T frames")
    body: str | None = Field(None, description="a preset (GET /v1/bodies) or a body_id (POST /v1/bodies); "
                             "defaults to the rigged outfit's, else neutral; with outfit_id it must be the "
                             "outfit's")
    influences: Literal[4, 8] | None = Field(None, description=INFLUENCES_HELP + " (default 4; with outfit_id: "
                                             "the rigged outfit's)")
    refine: bool | RefineOptions = Field(False, description="collision refinement post step: true or options")
    fit: bool = Field(False, description=FIT_HELP.split(";")[0] + " (with outfit, not outfit_id)")


class InnerLayer(BaseModel):
    """The garment worn under the refined one: its stream (T, Ni, 3) m over the same frames, its faces, and its
    thickness (m). The refined garment is pushed out of the body and then kept thickness + 1 mm outside this
    layer (which is itself first refined against the body, as /v1/refine would refine it alone)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    vertices: list[list[Vec3]] = Field(min_length=1, description="(T, Ni, 3) the inner garment's stream, metres, "
                                       "over the same T frames")
    faces: list[Tri] = Field(min_length=1, description="(Fi, 3) the inner garment's triangles, 0-based indices")
    thickness: float = Field(0.006, gt=0, le=0.05, allow_inf_nan=False, description="the inner layer's thickness H_in, metres")


class RefineRequest(BaseModel):
    """A garment stream (T, N, 3) m with its faces, the body motion that goes with it, the body preset."""

    model_config = ConfigDict(extra="forbid", strict=True, json_schema_extra={"examples": [
        {"vertices": [EXAMPLE_MESH["vertices"]] * 2, "faces": EXAMPLE_MESH["faces"],
         "motion": {"poses": [[0.0] * 72, [0.2] * 72]}, "options": {"relief_iterations": 0}}]})
    vertices: list[list[Vec3]] = Field(min_length=1, description="(T, N, 3) the garment's stream, metres, world "
                                       "space of each frame")
    faces: list[Tri] = Field(min_length=1, description="(F, 3) triangles: 0-based indices into a frame's vertices")
    motion: MotionInput = Field(description="the body's motion over the same T frames")
    body: str = Field("neutral", description="the body the garment is worn on: a preset (GET /v1/bodies) or a "
                      "body_id (POST /v1/bodies)")
    options: RefineOptions | None = Field(None, description="defaults: eps 3 mm, 3 iterations, 10 relief rounds")
    inner: InnerLayer | None = Field(None, description="a garment under this one: the stream is also pushed out "
                                     "of it (outer-through-inner removed)")
    rest_vertices: list[Vec3] | None = Field(None, min_length=3, description="(N, 3) the garment at rest, metres "
                                             "(the shape it was made in): with it, edges are kept near their rest "
                                             "lengths as animate keeps a rigged outfit's (the edge-limit pass: each "
                                             "edge pulled under 1.5x its rest length, or its input length if longer) "
                                             "instead of the relief pass; not with inner")


class AnimateResponse(BaseModel):
    """Posed vertices (T, N, 3) metres, the faces (F, 3), frames per second."""

    outfit_id: str = Field(description="the rigged outfit's id (POST /v1/outfits/animate); '' for a refined "
                           "stream (POST /v1/refine) and a garment's (POST /v1/garments/{name}/animate)")
    fps: float = Field(description="frames per second of the stream")
    vertices: list[list[Vec3]] = Field(description="(T, N, 3) posed vertices per frame, metres, world space")
    faces: list[list[int]] = Field(description="(F, 3) triangles: 0-based indices into a frame's vertices")


class Problem(BaseModel):
    """RFC 9457 problem details: every error answer, as application/problem+json."""

    type: str = Field(description="a stable URI per kind of error, https://drape.dev/problems/<kind>: "
                      "malformed-input (400), unauthorized (401), not-found (404), not-acceptable (406), "
                      "request-timeout (408), conflict (409), limit-exceeded (413), unsupported-media-type (415), "
                      "invalid-input (422), overloaded (503), store-full (507), http-<status> (routing: 404, 405), "
                      "internal-error (500)")
    title: str = Field(description="a short, fixed summary of the kind")
    status: int = Field(description="the HTTP status code")
    detail: str = Field(description="what was wrong, naming the request's field first when there is one "
                        "('motion.poses: ...'); cut to 1000 characters")
    field: str | None = Field(None, description="the request's field that is wrong, as the detail names it first "
                              "('motion.poses', 'keyframes[1].vertices', 'Accept'); null when the error is not "
                              "about one field (an extension member, RFC 9457 section 3.2)")
