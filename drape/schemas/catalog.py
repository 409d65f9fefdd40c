"""What the service embeds: body presets and motion clips."""

from __future__ import annotations

from pydantic import BaseModel, Field


class Health(BaseModel):
    status: str = Field(description="'ok' when the process is alive, 'ready' when serving")


class BodyInfo(BaseModel):
    """A body (a preset, or a user body registered by POST /v1/bodies): its skeleton and mesh sizes. Lengths
    in metres, T-pose rest, +Y up, facing +Z."""

    name: str
    preset: bool = Field(True, description="false for a user body (its name is its body_id)")
    num_vertices: int
    num_faces: int
    proxy_vertices: int = Field(description="vertices of the low-resolution collision proxy")
    height: float = Field(description="rest-pose height, metres")
    joint_names: list[str] = Field(description="24 joints in SMPL order")
    parents: list[int] = Field(description="parent index per joint, -1 for the root")
    rest_joints: list[list[float]] = Field(description="(24, 3) rest joint positions, metres")


class BodyList(BaseModel):
    bodies: list[BodyInfo]


class BodyRegistered(BaseModel):
    """A user body held by the service (POST /v1/bodies): use body_id wherever a body is named."""

    body_id: str = Field(description="'body-' + a hash of the body's arrays: the same upload gives the same id")
    num_vertices: int
    num_faces: int
    height: float = Field(description="rest-pose height, metres")


class BodyMesh(BaseModel):
    """A body's mesh and skeleton (GET /v1/bodies/{name}; npz by Accept: the same arrays)."""

    name: str
    preset: bool
    vertices: list[list[float]] = Field(description="(V, 3) rest-pose vertices, metres")
    faces: list[list[int]] = Field(description="(F, 3) vertex indices")
    weights: list[list[float]] = Field(description="(V, 24) skinning weights, rows summing to 1")
    joints: list[list[float]] = Field(description="(24, 3) rest joint positions, metres")
    parents: list[int] = Field(description="parent index per joint, -1 for the root")
    joint_names: list[str] = Field(description="24 joints in SMPL order")


class MotionInfo(BaseModel):
    """An embedded clip: poses (frames, 24, 3) axis-angle + root translation."""

    name: str
    frames: int
    fps: float
    duration: float = Field(description="seconds")


class MotionList(BaseModel):
    motions: list[MotionInfo]
