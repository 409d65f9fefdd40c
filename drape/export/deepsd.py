"""Export DeePSD to two ONNX files and write its manifest.

outfit.onnx: features (N, 6) float32, nbr_idx (N, K) int64, nbr_w (N, K) float32
             [, joint_mask (N, 24) float32 0/1 when the manifest has `joint_candidates`: the candidate joints
             of drape.geometry.queries.candidate_joints with those arguments]
             -> weights (N, 24) float32, blend_shapes (P, N, 3) float32 (= D_data + D_phys),
                blend_shapes_data (P, N, 3) float32 (D_data alone)   (N, K dynamic)
pose.onnx:   poses (T, 72) float32 axis-angle radians -> pose_keys (T, P) float32 (T dynamic)
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import torch

from drape.export.onnx_export import export_onnx, io_spec, sha256
from drape.models.deepsd import (
    NUM_JOINTS,
    DeployedMaskedOutfitNet,
    DeployedOutfitNet,
    OutfitNet,
    PoseNet,
)

DEFAULT_DIR = Path(__file__).resolve().parents[1] / "assets" / "models" / "deepsd"


def example_inputs(n: int = 64, k: int = 6) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    x = torch.randn(n, 6, generator=g)
    idx = torch.randint(0, n, (n, k), generator=g)
    w = torch.full((n, k), 1.0 / k)
    return x, idx, w


def export_deepsd(outfit: OutfitNet, pose: PoseNet, out_dir: str | Path, joint_mask: bool = False) -> dict[str, Path]:
    """Write outfit.onnx and pose.onnx into out_dir; returns their paths. joint_mask: the outfit network takes
    the candidate joints as a fourth input (a model trained with `joint_candidates`)."""
    out_dir = Path(out_dir)
    n, k, t = torch.export.Dim("num_vertices", min=4), torch.export.Dim("max_neighbours", min=2), torch.export.Dim("frames", min=1)
    deployed: torch.nn.Module = DeployedOutfitNet(outfit)
    inputs: tuple[torch.Tensor, ...] = example_inputs()
    names = ["features", "nbr_idx", "nbr_w"]
    shapes: tuple[dict[int, torch.export.Dim], ...] = ({0: n}, {0: n, 1: k}, {0: n, 1: k})
    if joint_mask:
        mask = (torch.arange(NUM_JOINTS)[None] % 6 == torch.arange(len(inputs[0]))[:, None] % 6).float()
        deployed, inputs, names, shapes = (DeployedMaskedOutfitNet(outfit), (*inputs, mask), [*names, "joint_mask"],
                                           (*shapes, {0: n}))
    outfit_path = export_onnx(deployed.eval(), inputs, out_dir / "outfit.onnx", names,
                              ["weights", "blend_shapes", "blend_shapes_data"], shapes)
    pose_path = export_onnx(
        pose.eval(), (torch.zeros(3, 72),), out_dir / "pose.onnx", ["poses"], ["pose_keys"], ({0: t},),
    )
    return {"outfit": outfit_path, "pose": pose_path}


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def write_manifest(out_dir: str | Path, version: str, config: dict, evaluation: dict | None, trained: bool) -> Path:
    """manifest.json beside the ONNX files: version, sha256, I/O specs, training config and commit, eval table."""
    out_dir = Path(out_dir)
    files = {}
    for name in ("outfit", "pose"):
        path = out_dir / f"{name}.onnx"
        files[name] = {"file": path.name, "sha256": sha256(path), "bytes": path.stat().st_size, **io_spec(path)}
    manifest = {
        "name": "deepsd",
        "version": version,
        "trained": trained,
        "files": files,
        # how the runtime makes the outfit network's joint_mask input (None: the network has no such input)
        "joint_candidates": config.get("joint_candidates"),
        "training": {"config": config, "commit": git_commit()},
        "evaluation": evaluation,
    }
    path = out_dir / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2, default=_json_default) + "\n")
    return path


def _json_default(o: object) -> object:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, tuple):
        return list(o)
    raise TypeError(type(o).__name__)


def _latest_run(ckpt_dir: str | Path) -> tuple[dict, dict] | None:
    """The run's chosen checkpoint (`best.pt`, chosen on the validation split by
    drape.training.deepsd_validation, when present; else the latest) and its record: config, file, steps done,
    training seconds, and the validation figures when a checkpoint was chosen on them."""
    ckpt_dir = Path(ckpt_dir)
    found = sorted(ckpt_dir.glob("step_*.pt"))
    if not found:
        return None
    chosen = ckpt_dir / "best.pt" if (ckpt_dir / "best.pt").exists() else found[-1]
    state = torch.load(chosen, weights_only=True)
    record = {"config": json.loads(state["config"]), "file": chosen.name, "steps_done": state["done"].tolist(),
              "train_seconds": round(float(state["elapsed"]), 1), "device": state.get("device", "unknown")}
    if chosen.name == "best.pt" and (ckpt_dir / "validation.json").exists():
        record["validation"] = json.loads((ckpt_dir / "validation.json").read_text())
    return state, record


def load_checkpoint(ckpt_dir: str | Path) -> tuple[OutfitNet, PoseNet, dict]:
    """The latest checkpoint's networks and its training config."""
    run = _latest_run(ckpt_dir)
    if run is None:
        raise FileNotFoundError(f"no checkpoint in {ckpt_dir}; run `drape train deepsd` first")
    state, record = run
    outfit, pose = OutfitNet(), PoseNet()
    outfit.load_state_dict(state["outfit"])
    pose.load_state_dict(state["pose"])
    config = record.pop("config")
    config["_checkpoint"] = record
    if config.get("init_checkpoints"):
        config["_started_from"] = started_from(config["init_checkpoints"])
    return outfit, pose, config


def started_from(ckpt_dir: str | Path) -> list[dict]:
    """A fine-tune's ancestry, nearest first: each earlier run's config, steps and training time,
    followed through their own `init_checkpoints` (a run no longer on disk ends the list)."""
    chain: list[dict] = []
    base: str | Path | None = ckpt_dir
    while base:
        run = _latest_run(base)
        if run is None:
            chain.append({"checkpoints": str(base), "missing": True})
            break
        record = run[1]
        chain.append({"checkpoints": str(base), **record})
        base = record["config"].get("init_checkpoints")
    return chain


def export_deepsd_from_checkpoints(ckpt_dir: str | Path, out_dir: str | Path, init: bool = False) -> list[Path]:
    """Export the latest checkpoint (or, with init, a freshly initialised model) and write the manifest.

    An existing evaluation table in the manifest is dropped: it belonged to other weights.
    """
    if init:
        torch.manual_seed(0)
        outfit, pose, config = OutfitNet(), PoseNet(), {"untrained": True}
    else:
        outfit, pose, config = load_checkpoint(ckpt_dir)
    paths = export_deepsd(outfit, pose, out_dir, joint_mask=config.get("joint_candidates") is not None)
    manifest = write_manifest(out_dir, version=VERSION, config=config, evaluation=None, trained=not init)
    return [paths["outfit"], paths["pose"], manifest]


VERSION = "0.13.0"
