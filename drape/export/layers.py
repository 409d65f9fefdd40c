"""MGN's layer networks -> model folders the runtime serves.

Inner-layer network of one inner template (drape/assets/models/mgn_inner/<inner>/):

- pose.onnx: poses (T, 72) float32 axis-angle rad -> pose_keys (T, K) (the basis coefficients); T dynamic.
- rig.npz: the template and what the runtime poses it with (drape.runtime.deepsd.pose_outfit):
  vertices (N, 3) float32 m (rest pose on the body), faces (F, 3) int32, weights (N, 24) float32 (from the body),
  blend_shapes (K, N, 3) float32 m (P_D2G).
- manifest.json: name "mgn_inner", version, template, pair, body, the model config, the training config and
  summary (the validation record of every measured step and the chosen one), DeePSD's served rig of the same
  template on the same validation split (`deepsd_validation`), `served` ("mgn_inner" where the network's
  validation score is lower, else "deepsd": the runtime poses the inner layer with the served one), the
  evaluation table when measured, and each file's sha256.

Outer-layer network of one combination (drape/assets/models/mgn_outer/<inner>_<outer>/):
- outer.onnx: motion (S, W, 78) float32 (drape.geometry.character_space.motion_features, windows of W frames),
  thickness (S, 1) float32 m, inner_keys (S, W, Ki) float32 (the inner network's pose keys) -> outer_keys
  (S, W, K); S and W dynamic.
- rig.npz: as the inner's, for the outer template (blend_shapes: the outer network's basis).
- manifest.json: name "mgn_outer", version, template, inner, the inner network it reads (`inner_network`:
  version, pose.onnx sha256), configs, the validation record, DeePSD's outer rig on the same validation
  sequences, `served`, the evaluation table when measured, each file's sha256.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from drape.export.onnx_export import export_onnx, io_spec, sha256
from drape.models.layers import (
    InnerCoefficientsGraph,
    InnerPSD,
    OuterCoefficientsGraph,
    OuterTransformer,
)

VERSION = "0.1.0"
MODEL_DIR = Path(__file__).resolve().parents[1] / "assets" / "models" / "mgn_inner"
OUTER_DIR = Path(__file__).resolve().parents[1] / "assets" / "models" / "mgn_outer"
OUTER_VERSION = "0.1.0"


def export_inner(model: InnerPSD, out: str | Path, *, vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray,
                 manifest: dict) -> list[Path]:
    """Write pose.onnx, rig.npz and manifest.json (`manifest` plus name, version, model config and the files'
    sha256) under `out`; returns their paths. vertices (N, 3) m, faces (F, 3), weights (N, 24)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model.eval()
    if vertices.shape != (model.cfg.num_vertices, 3) or weights.shape != (model.cfg.num_vertices, 24):
        raise ValueError(f"template {vertices.shape} / weights {weights.shape} do not match the model's "
                         f"{model.cfg.num_vertices} vertices")
    frames = torch.export.Dim("frames", min=1, max=100_000)
    pose = export_onnx(InnerCoefficientsGraph(model), (torch.zeros(2, 72),), out / "pose.onnx", ["poses"],
                       ["pose_keys"], ({0: frames},))
    rig = out / "rig.npz"
    np.savez(rig, vertices=np.asarray(vertices, np.float32), faces=np.asarray(faces, np.int32),
             weights=np.asarray(weights, np.float32), blend_shapes=model.basis.detach().numpy().astype(np.float32))
    files = [pose, rig]
    record = {"name": "mgn_inner", "version": VERSION, "model_config": model.cfg.to_dict(), **manifest,
              "files": {p.stem: {"file": p.name, "sha256": sha256(p), "bytes": p.stat().st_size,
                                 **(io_spec(p) if p.suffix == ".onnx" else {})} for p in files}}
    path = out / "manifest.json"
    path.write_text(json.dumps(record, indent=2) + "\n")
    return [*files, path]


def export_outer(model: OuterTransformer, out: str | Path, *, vertices: np.ndarray, faces: np.ndarray,
                 weights: np.ndarray, manifest: dict) -> list[Path]:
    """Write outer.onnx, rig.npz and manifest.json under `out`; returns their paths. vertices (No, 3) m,
    faces (F, 3), weights (No, 24)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model.eval()
    cfg = model.cfg
    if vertices.shape != (cfg.num_vertices, 3) or weights.shape != (cfg.num_vertices, 24):
        raise ValueError(f"template {vertices.shape} / weights {weights.shape} do not match the model's "
                         f"{cfg.num_vertices} vertices")
    windows = torch.export.Dim("windows", min=1, max=100_000)
    frames = torch.export.Dim("frames", min=1, max=512)
    args = (torch.zeros(3, cfg.window, 78), torch.full((3, 1), 0.006), torch.zeros(3, cfg.window, cfg.num_inner_keys))
    graph = export_onnx(OuterCoefficientsGraph(model), args, out / "outer.onnx", ["motion", "thickness", "inner_keys"],
                        ["outer_keys"], ({0: windows, 1: frames}, {0: windows}, {0: windows, 1: frames}))
    rig = out / "rig.npz"
    np.savez(rig, vertices=np.asarray(vertices, np.float32), faces=np.asarray(faces, np.int32),
             weights=np.asarray(weights, np.float32), blend_shapes=model.basis.detach().numpy().astype(np.float32))
    files = [graph, rig]
    record = {"name": "mgn_outer", "version": OUTER_VERSION, "model_config": cfg.to_dict(), **manifest,
              "files": {p.stem: {"file": p.name, "sha256": sha256(p), "bytes": p.stat().st_size,
                                 **(io_spec(p) if p.suffix == ".onnx" else {})} for p in files}}
    path = out / "manifest.json"
    path.write_text(json.dumps(record, indent=2) + "\n")
    return [*files, path]
