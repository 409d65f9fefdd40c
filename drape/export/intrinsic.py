"""The intrinsic garment space of one template -> a model folder the runtime serves.

- shape_encode.onnx (N_E): vertices (T, N, 3) float32 m in each frame's character space -> descriptor (T, D).
- shape_decode.onnx (N_D): descriptor (T, D) -> vertices (T, N, 3) m, character space.
- encode.onnx (M_E, F_E): descriptor (T, D), windows (T, W + 1, 24, 3) float32 m (character space) -> latent (T, Z).
- decode.onnx (M_E, F_D): latent (T, Z), windows -> descriptor (T, D). T is dynamic in all four.
  The runtime composes them (vertices -> latent: shape_encode then encode; latent -> vertices: decode then
  shape_decode); apart, the shape autoencoder gives the descriptor-interpolation baseline, and the large
  first/last layers of N_E/N_D are stored once.
- template.npz: the template in rest pose on its body: vertices (N, 3) float32 m, faces (F, 3) int32.
- manifest.json: name "intrinsic", version, template name, body, fps, the motion window, the model
  config, the latent statistics (`latent_mean`, `latent_std`: (Z,) over the training parameter sets'
  mean latents; `sample` draws from them), the training summary, the evaluation table when measured,
  and each file's sha256.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from drape.export.onnx_export import export_onnx, io_spec, sha256
from drape.models.intrinsic import (
    DecodeGraph,
    EncodeGraph,
    IntrinsicSpace,
    ShapeDecodeGraph,
    ShapeEncodeGraph,
)

VERSION = "0.3.1"  # 0.3.1: keyframe_shrink (drape.training.intrinsic_shrink) on 0.3.0's networks


def export_intrinsic(model: IntrinsicSpace, out: str | Path, *, template: str = "template",
                     rest_vertices: np.ndarray | None = None, faces: np.ndarray | None = None,
                     body: str = "neutral", fps: float = 30.0, latent_mean: np.ndarray | None = None,
                     latent_std: np.ndarray | None = None, extra: dict | None = None) -> list[Path]:
    """Write the four ONNX files, template.npz (when rest_vertices and faces are given) and
    manifest.json under `out`; returns their paths. rest_vertices (N, 3) m, faces (F, 3)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = model.cfg
    model.eval()
    frames = torch.export.Dim("frames", min=1, max=100_000)
    v = torch.zeros(2, cfg.num_vertices, 3)
    s = torch.zeros(2, cfg.descriptor)
    w = torch.zeros(2, cfg.window + 1, 24, 3)
    z = torch.zeros(2, cfg.latent)
    se = export_onnx(ShapeEncodeGraph(model), (v,), out / "shape_encode.onnx", ["vertices"], ["descriptor"],
                     ({0: frames},))
    sd = export_onnx(ShapeDecodeGraph(model), (s,), out / "shape_decode.onnx", ["descriptor"], ["vertices"],
                     ({0: frames},))
    enc = export_onnx(EncodeGraph(model), (s, w), out / "encode.onnx", ["descriptor", "windows"], ["latent"],
                      ({0: frames}, {0: frames}))
    dec = export_onnx(DecodeGraph(model), (z, w), out / "decode.onnx", ["latent", "windows"], ["descriptor"],
                      ({0: frames}, {0: frames}))
    files = [enc, dec, se, sd]
    if rest_vertices is not None and faces is not None:
        if rest_vertices.shape != (cfg.num_vertices, 3):
            raise ValueError(f"rest_vertices {rest_vertices.shape} do not match the model's {cfg.num_vertices} vertices")
        tpl = out / "template.npz"
        np.savez(tpl, vertices=np.asarray(rest_vertices, np.float32), faces=np.asarray(faces, np.int32))
        files.append(tpl)
    mean = np.zeros(cfg.latent) if latent_mean is None else np.asarray(latent_mean, np.float64)
    std = np.ones(cfg.latent) if latent_std is None else np.asarray(latent_std, np.float64)
    manifest = {"name": "intrinsic", "version": VERSION, "template": template, "body": body, "fps": float(fps),
                "window": cfg.window, "model_config": cfg.to_dict(),
                "latent_mean": [round(float(x), 6) for x in mean], "latent_std": [round(float(x), 6) for x in std],
                **(extra or {}),
                "files": {p.stem: {"file": p.name, "sha256": sha256(p), "bytes": p.stat().st_size,
                            **(io_spec(p) if p.suffix == ".onnx" else {})}
                          for p in files}}
    path = out / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2) + "\n")
    return [*files, path]
