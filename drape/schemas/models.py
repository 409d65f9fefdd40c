"""What /v1/models reports."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field


class TensorSpec(BaseModel):
    name: str
    shape: list[int] = Field(description="-1 for a dynamic axis")
    datatype: str


class ModelFile(BaseModel):
    file: str
    sha256: str
    bytes: int
    inputs: list[TensorSpec]
    outputs: list[TensorSpec]


class ModelInfo(BaseModel):
    name: str
    version: str
    trained: bool
    files: dict[str, ModelFile]
    evaluation: dict[str, Any] | None = None


class ModelList(BaseModel):
    models: list[ModelInfo]
