"""Choose between outer-layer training runs on one validation split and rule.

Each run chooses its step on its own config's validation (drape.training.layers_outer.train); runs whose configs
validate differently (other clips, other caps) are compared here on ONE config's: the validation sequences, the
validation clips and the caps of `--config`. For each checkpoint folder: the network of its best.pt (built by the
model config it was trained with, read from its last step file) measured by layers_outer.measure_all; with
`--shipped FOLDER`, an exported network (outer.onnx + rig.npz, as `drape.runtime.layers.OuterModel` serves it, e.g.
the one a retraining would replace) measured by the same code; DeePSD's
outer rig (as served without a network) is measured beside them by the same code. Lower score wins (RMSE mm
against the simulation, plus layers_outer.PENALTY where a cap is exceeded). The held-out evaluation (`drape eval
layers`) plays no part.

With `--thickness`, each network's response to the inner thickness H_in too: the 10th percentile of the outer
layer's distance to the served inner layer (over the vertex-frames over it, as drape.sim.quality measures the
simulation's `outer_inner_gap_p10_m`) on each validation sequence at its own H_in, against the simulation's own
figure (|error| mm, mean over the sequences), and posed at both ends of the config's thickness range (the gap's
change over the range's change: the simulation keeps its 10th percentile at about H_in + 0.5 mm, a slope of 1).

Run: .venv/bin/python -m bench.layers_outer_runs --config drape/training/configs/X.json checkpoints/A checkpoints/B
     [--shipped drape/assets/models/mgn_outer/<inner>_<outer>] [--thickness]
(a few minutes on the 2-core machine; needs the pair's sequences under data/layers)
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from drape.models.layers import OuterConfig, OuterTransformer
from drape.runtime.deepsd import pose_outfit
from drape.runtime.layers import OuterModel
from drape.training import layers_outer
from drape.training.config_file import read_config


def run_network(folder: Path, task: layers_outer.OuterTask) -> tuple[OuterTransformer, int]:
    """The chosen network of a run's checkpoint folder -> (model in eval mode, its step)."""
    last = sorted(folder.glob("step_*.pt"))[-1]
    trained_by = json.loads(torch.load(last, weights_only=True)["config"])
    model = OuterTransformer(OuterConfig(num_vertices=len(task.vertices),
                                         num_inner_keys=task.inner_model.rig.blend_shapes.shape[0],
                                         **trained_by["model"]))
    best = torch.load(folder / "best.pt", weights_only=True)
    model.load_state_dict(best["model"])
    model.eval()
    return model, int(best["step"])


def pose_shipped(net: OuterModel, task: layers_outer.OuterTask, seq: layers_outer.Sequence) -> np.ndarray:
    """An exported outer network posed along a prepared sequence as the runtime poses it (its ONNX graph on the
    sequence's windows, blended; its own rig) -> (T, No, 3) m."""
    keys = net.keys_of_features(seq.features, seq.thickness, seq.inner_keys)
    return pose_outfit(net.vertices, net.rig, keys, task.body.joints, seq.poses, seq.trans)


def gap_p10(task: layers_outer.OuterTask, seq: layers_outer.Sequence, v: np.ndarray) -> float:
    """The 10th percentile (m) of an outer layer's (T, No, 3) distance to the served inner layer along seq, over
    the vertex-frames over it (drape.sim.quality.outer_inner_distance's `covered`), every 3rd frame."""
    from drape.sim.quality import outer_inner_distance

    sd, covered = outer_inner_distance(v[::3], seq.inner[::3], task.inner_faces)
    return float(np.percentile(sd[covered], 10))


def thickness_response(task: layers_outer.OuterTask, seqs: list[layers_outer.Sequence],
                       pose: Callable[[layers_outer.Sequence], np.ndarray]) -> str:
    """The --thickness line of a poser (see the module docstring)."""
    manifest = json.loads((task.data_dir / "manifest.json").read_text())
    items = {it["key"]: it for it in manifest["items"] + manifest["rejected"]}
    low, high = task.cfg["thickness"]
    errors, slopes = [], []
    for s in seqs:
        errors.append(abs(gap_p10(task, s, pose(s)) - items[s.key]["stats"]["outer_inner_gap_p10_m"]))
        ends = [gap_p10(task, s, pose(replace(s, thickness=h))) for h in (low, high)]
        slopes.append((ends[1] - ends[0]) / (high - low))
    return f"gap p10 |error| {1e3 * np.mean(errors):.2f} mm, slope over H_in [{low}, {high}] m {np.mean(slopes):.2f}"


def row(name: str, figures: dict) -> str:
    return (f"{name:44} {figures['score']:9.2f} {figures['rmse_mm']:8.2f} {figures['l_coll_pct']:7.2f} "
            f"{figures['h_coll_pct']:7.2f} {figures['clip_l_coll_pct']:7.2f} {figures['clip_h_coll_pct']:7.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", required=True, help="the config whose validation split and caps judge")
    parser.add_argument("runs", nargs="*", type=Path, help="checkpoint folders (best.pt, step_*.pt)")
    parser.add_argument("--shipped", type=Path, action="append", default=[],
                        help="an exported network's folder (outer.onnx, rig.npz, manifest.json); repeatable")
    parser.add_argument("--thickness", action="store_true", help="also measure each network's response to H_in")
    args = parser.parse_args()
    cfg = read_config(args.config, "mgn_outer")
    task = layers_outer.OuterTask(cfg)
    seqs, clips = task.sequences("test"), layers_outer.validation_clips(task)
    print(f"validation of {args.config}: {len(seqs)} sequences, clips {', '.join(s.motion for s in clips)}; "
          f"caps {layers_outer.collision_caps(cfg)}, clips L-Coll <= {cfg.get('max_clip_l_coll_pct', 100.0)}%, "
          f"H-Coll <= {cfg.get('max_clip_h_coll_pct', 100.0)}%")
    print(f"{'network':44} {'score':>9} {'RMSE mm':>8} {'L-Coll':>7} {'H-Coll':>7} {'clip L':>7} {'clip H':>7}")
    with torch.no_grad():
        for folder in args.runs:
            model, step = run_network(folder, task)
            figures = layers_outer.measure_all(task, seqs, clips, lambda s, m=model: layers_outer.pose_outer(m, task, s))
            print(row(f"{folder.name} (step {step})", figures), flush=True)
            if args.thickness:
                print("    " + thickness_response(task, seqs, lambda s, m=model: layers_outer.pose_outer(m, task, s)),
                      flush=True)
    for folder in args.shipped:
        net = OuterModel(folder)
        if net.inner_sha256 != task.inner_model.sha256:
            raise SystemExit(f"{folder} was trained beside another inner network than the one served")
        figures = layers_outer.measure_all(task, seqs, clips, lambda s, n=net: pose_shipped(n, task, s))
        print(row(f"{folder.name} (exported)", figures), flush=True)
        if args.thickness:
            print("    " + thickness_response(task, seqs, lambda s, n=net: pose_shipped(n, task, s)), flush=True)
    print(row("DeePSD's outer rig", layers_outer.deepsd_validation(task, seqs, clips)))


if __name__ == "__main__":
    main()
