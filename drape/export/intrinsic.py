"""The intrinsic garment space of one template -> two ONNX files (`encode`, `decode`) + manifest.

encode.onnx: vertices (T, N, 3) float32 m and windows (T, W + 1, 24, 3) float32 m, both in each
frame's character space -> z (T, latent). decode.onnx: z (T, latent), windows -> vertices (T, N, 3).
T is dynamic. The manifest records the config, the model config, the template's faces count, the
training summary and each file's sha256.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from drape.export.onnx_export import export_onnx, io_spec, sha256
from drape.models.intrinsic import DecodeGraph, EncodeGraph, IntrinsicSpace

VERSION = "0.1.0"


def export_intrinsic(model: IntrinsicSpace, out: str | Path, extra: dict | None = None) -> list[Path]:
    """Write encode.onnx, decode.onnx and manifest.json under `out`; returns their paths."""
    out = Path(out)
    cfg = model.cfg
    model.eval()
    frames = torch.export.Dim("frames", min=1, max=100_000)
    v = torch.zeros(2, cfg.num_vertices, 3)
    w = torch.zeros(2, cfg.window + 1, 24, 3)
    z = torch.zeros(2, cfg.latent)
    enc = export_onnx(EncodeGraph(model), (v, w), out / "encode.onnx", ["vertices", "windows"], ["latent"],
                      ({0: frames}, {0: frames}))
    dec = export_onnx(DecodeGraph(model), (z, w), out / "decode.onnx", ["latent", "windows"], ["vertices"],
                      ({0: frames}, {0: frames}))
    manifest = {"name": "intrinsic", "version": VERSION, "model_config": cfg.to_dict(), **(extra or {}),
                "files": {p.stem: {"file": p.name, "sha256": sha256(p), **io_spec(p)} for p in (enc, dec)}}
    path = out / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2) + "\n")
    return [enc, dec, path]
