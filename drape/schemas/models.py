"""What /v1/models reports."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field


class TensorSpec(BaseModel):
    """An input or output of an ONNX graph."""

    name: str = Field(description="the tensor's name in the graph")
    shape: list[int] = Field(description="-1 for a dynamic axis")
    datatype: str = Field(description="the element type: 'FP32', 'INT64', 'INT32' (KServe v2 names), else "
                                     "ONNX's TensorProto number as text")


class ModelFile(BaseModel):
    """One ONNX file of a model, as its manifest.json records it."""

    file: str = Field(description="the file's name in the model's directory")
    sha256: str = Field(description="hex SHA-256 of the file's bytes")
    bytes: int = Field(description="the file's size, bytes")
    inputs: list[TensorSpec] = Field(description="the graph's inputs")
    outputs: list[TensorSpec] = Field(description="the graph's outputs")


class ModelInfo(BaseModel):
    """A loaded model: 'deepsd' (outfit rigging), then 'intrinsic-<template>' per garment template, then the served
    layer networks, 'mgn_inner-<inner>' and 'mgn_outer-<inner>_<outer>'."""

    name: str = Field(description="what GET /v1/models/{name} takes")
    version: str = Field(description="the manifest's version")
    trained: bool = Field(description="whether the weights come from training (false: exported untrained, "
                                      "e.g. a test build)")
    files: dict[str, ModelFile] = Field(description="the model's ONNX files by role (DeePSD: 'outfit', "
                                                 "'pose'; MGN: 'pose' (inner), 'outer')")
    evaluation: dict[str, Any] | None = Field(None, description="the manifest's evaluation tables as recorded "
                                              "(settings and metrics); null when none was run")


class ModelList(BaseModel):
    """Every loaded model (GET /v1/models)."""

    models: list[ModelInfo] = Field(description="the DeePSD model first, then one intrinsic model per garment "
                                                "template, then the served layer networks")
