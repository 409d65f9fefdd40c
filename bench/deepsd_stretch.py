"""How far do DeePSD's posed edges stretch with each `densify_edge`? On the VALIDATION split only: the config's
validation outfits at 400 and 3,000 vertices (as bench.deepsd_coarse), posed by the served 4-influence rig along
every 10th frame of the validation motions; per outfit the largest edge length over its rest length and the
share of edge-frames over 2x, then the means over outfits (and the worst). bench.deepsd_coarse's score (inside %
+ edge error mm) does not see these tails; this does.

Run: .venv/bin/python -m bench.deepsd_stretch [--config CONFIG]  (about 3 minutes on the 2-core machine).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np

from drape.assets.body import load_body
from drape.geometry.mesh import unique_edges
from drape.runtime.deepsd import DeePSDModel, pose_outfit
from drape.runtime.sparse_rig import fit_poses, sparse_rig
from drape.training.deepsd_data import load_outfit
from drape.training.deepsd_validation import validation_motions, validation_specs

EDGES = {"none": None, "0.04": 0.04, "0.025": 0.025, "0.025r": 0.025}  # r: densify_ring


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="drape/training/configs/deepsd_candidates_loose_prior.json")
    args = parser.parse_args()
    with open(args.config) as fh:
        cfg = json.load(fh)
    models = {name: DeePSDModel(densify_edge=e, densify_ring=name.endswith("r")) for name, e in EDGES.items()}
    poses_fit = fit_poses()
    keys_fit = models["none"].pose_keys(poses_fit)
    for vertices in (400, 3000):
        per_model: dict[str, list[tuple[float, float]]] = {m: [] for m in models}
        for spec in validation_specs(cfg):
            spec = replace(spec, vertices=vertices)
            v, f = load_outfit(spec)
            body = load_body(spec.body)
            e = unique_edges(f)
            rest = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
            motions = validation_motions(cfg, spec.body)
            poses = np.concatenate([m.poses[::10] for m in motions]).astype(np.float64)
            trans = np.concatenate([m.trans[::10] for m in motions]).astype(np.float64)
            row = []
            for name, model in models.items():
                r = sparse_rig(v, model.rig(v, f, body), body.joints, 4, poses_fit, keys_fit)
                frames = pose_outfit(v, r, model.pose_keys(poses), body.joints, poses, trans)
                ratio = np.linalg.norm(frames[:, e[:, 0]] - frames[:, e[:, 1]], axis=2) / rest
                per_model[name].append((float(ratio.max()), float(np.mean(ratio > 2))))
                row.append(f"{name}: largest {ratio.max():.2f}x, over 2x {np.mean(ratio > 2):.3%}")
            print(f"{vertices:5d} {spec.types:20} " + " | ".join(row), flush=True)
        for name, rows in per_model.items():
            a = np.array(rows)
            print(f"{vertices:5d} densify_edge {name:6}: largest edge / rest, mean over outfits {a[:, 0].mean():.2f}x "
                  f"(worst {a[:, 0].max():.2f}x); edge-frames over 2x {100 * a[:, 1].mean():.3f}%")


if __name__ == "__main__":
    main()
