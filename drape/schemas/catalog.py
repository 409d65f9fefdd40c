"""What the service embeds: body presets and motion clips."""

from __future__ import annotations

from pydantic import BaseModel, Field


class Health(BaseModel):
    status: str = Field(description="'ok' when the process is alive, 'ready' when serving")


class BodyInfo(BaseModel):
    """A body preset: its skeleton and mesh sizes. Lengths in metres, T-pose rest, +Y up, facing +Z."""

    name: str
    num_vertices: int
    num_faces: int
    proxy_vertices: int = Field(description="vertices of the low-resolution collision proxy")
    height: float = Field(description="rest-pose height, metres")
    joint_names: list[str] = Field(description="24 joints in SMPL order")
    parents: list[int] = Field(description="parent index per joint, -1 for the root")
    rest_joints: list[list[float]] = Field(description="(24, 3) rest joint positions, metres")


class BodyList(BaseModel):
    bodies: list[BodyInfo]


class MotionInfo(BaseModel):
    """An embedded clip: poses (frames, 24, 3) axis-angle + root translation."""

    name: str
    frames: int
    fps: float
    duration: float = Field(description="seconds")


class MotionList(BaseModel):
    motions: list[MotionInfo]
