"""What the service embeds: body presets and motion clips."""

from __future__ import annotations

from pydantic import BaseModel, Field


class Health(BaseModel):
    """A probe's answer (GET /healthz, GET /readyz)."""

    status: str = Field(description="'ok' (GET /healthz: the process is alive), 'ready' (GET /readyz: models "
                                    "loaded, serving) or 'starting' (GET /readyz's 503 until then)")


class BodyInfo(BaseModel):
    """A body (a preset, or a user body registered by POST /v1/bodies): its skeleton and mesh sizes. Lengths
    in metres, T-pose rest, +Y up, facing +Z."""

    name: str = Field(description="the preset's name, or a user body's body_id: what `body` takes in requests")
    preset: bool = Field(True, description="false for a user body (its name is its body_id)")
    num_vertices: int = Field(description="V, vertices of the body mesh")
    num_faces: int = Field(description="F, triangles of the body mesh")
    proxy_vertices: int = Field(description="vertices of the low-resolution collision proxy")
    height: float = Field(description="rest-pose height, metres")
    joint_names: list[str] = Field(description="24 joints in SMPL order")
    parents: list[int] = Field(description="parent index per joint, -1 for the root")
    rest_joints: list[list[float]] = Field(description="(24, 3) rest joint positions, metres")


class BodyList(BaseModel):
    """The bodies a request can name (GET /v1/bodies)."""

    bodies: list[BodyInfo] = Field(description="the presets, then the registered user bodies")


class BodyRegistered(BaseModel):
    """A user body held by the service (POST /v1/bodies): use body_id wherever a body is named."""

    body_id: str = Field(description="'body-' + a hash of the body's arrays: the same upload gives the same id")
    num_vertices: int = Field(description="V, vertices of the body mesh")
    num_faces: int = Field(description="F, triangles of the body mesh")
    height: float = Field(description="rest-pose height, metres")
    registrations: int = Field(1, description="how many registrations hold the body: the same body registered "
                                              "again (by any client) counts once more, each DELETE takes one back, "
                                              "and the last forgets it")


class BodyMesh(BaseModel):
    """A body's mesh and skeleton (GET /v1/bodies/{name}; npz by Accept: the same arrays)."""

    name: str = Field(description="the preset's name or the user body's body_id")
    preset: bool = Field(description="false for a user body (POST /v1/bodies)")
    vertices: list[list[float]] = Field(description="(V, 3) rest-pose vertices, metres")
    faces: list[list[int]] = Field(description="(F, 3) vertex indices")
    weights: list[list[float]] = Field(description="(V, 24) skinning weights, rows summing to 1")
    joints: list[list[float]] = Field(description="(24, 3) rest joint positions, metres")
    parents: list[int] = Field(description="parent index per joint, -1 for the root")
    joint_names: list[str] = Field(description="24 joints in SMPL order")


class MotionInfo(BaseModel):
    """An embedded clip: poses (frames, 24, 3) axis-angle + root translation."""

    name: str = Field(description="what a request's motion.clip takes")
    frames: int = Field(description="T, frames of the clip")
    fps: float = Field(description="the clip's frame rate, frames per second (a request's motion.fps does not "
                                   "change it)")
    duration: float = Field(description="frames / fps, seconds")


class MotionList(BaseModel):
    """The embedded motion clips (GET /v1/motions)."""

    motions: list[MotionInfo] = Field(description="every clip, by name")
