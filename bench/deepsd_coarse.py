"""Does DeePSD rig a coarse garment (long edges, as garments made in other tools often come: the ArcSim t-shirt
of ../shared/data/external has 426 vertices, 67 mm mean edges; DeePSD trained on 800-4,500-vertex outfits; at 3,000 vertices the validation outfits have 13-36 mm)
better when it reads it subdivided (drape.geometry.mesh.densify, its own vertices answered from the finer
mesh)? On the VALIDATION split only (never the held-out table): the config's validation outfit types and seeds,
generated at `--vertices` (default 400) on their validation bodies, posed along the validation motions and
measured as the checkpoint choice measures them (drape.training.deepsd_validation.measure_poser: inside % by
closest triangle over the garment's own vertices, edge error mm; the 4-influence served rig), for: the
nearest-body-weights baseline and the shipped model with each `densify_edge` (none: as it is).

Run: .venv/bin/python -m bench.deepsd_coarse [--config CONFIG] [--vertices 400] [--edges none,0.04,0.025,0.015]
(about 15 minutes on the 2-core machine).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from drape.assets.body import load_body
from drape.geometry.lbs import pose_mesh
from drape.geometry.mesh import mean_edge_length
from drape.geometry.queries import nearest_vertex_weights
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, pose_outfit
from drape.runtime.sparse_rig import fit_poses, sparse_rig
from drape.training.deepsd_data import load_outfit
from drape.training.deepsd_validation import measure_poser, summarise, validation_specs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="drape/training/configs/deepsd_candidates_loose_prior.json")
    parser.add_argument("--vertices", type=int, default=400)
    parser.add_argument("--edges", default="none,0.04,0.025,0.015", help="densify_edge values (m); none: as it is; "
                        "a value ending in 'r' (e.g. 0.025r) also averages over the finer one-ring (densify_ring)")
    args = parser.parse_args()
    with open(args.config) as fh:
        cfg = json.load(fh)
    models = {e: DeePSDModel(MODEL_DIR, densify_edge=None if e == "none" else float(e.rstrip("r")),
                             densify_ring=e.endswith("r")) for e in args.edges.split(",")}
    first = next(iter(models.values()))
    print(f"DeePSD {first.manifest['version']}; validation of {args.config}; outfits at {args.vertices} vertices")
    poses_fit = fit_poses()
    keys_fit = first.pose_keys(poses_fit)
    influences = cfg["validation"]["influences"]
    totals: dict[str, list[dict]] = {"baseline": [], **{f"edge {m}": [] for m in models}}
    print(f"{'outfit':28} {'vertices':>8} {'edge mm':>8} {'method':12} {'inside %':>9} {'edge err mm':>11}")
    for spec in validation_specs(cfg):
        spec = replace(spec, vertices=args.vertices)
        v, f = load_outfit(spec)
        body = load_body(spec.body)
        posers: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {}
        w, joints = nearest_vertex_weights(v, body.vertices, body.weights), body.joints
        posers["baseline"] = lambda p, t, w=w, v=v, j=joints: pose_mesh(v, w, j, p, t)
        for m, model in models.items():
            r = sparse_rig(v, model.rig(v, f, body), joints, influences, poses_fit, keys_fit)
            posers[f"edge {m}"] = lambda p, t, r=r, v=v, j=joints, model=model: pose_outfit(
                v, r, model.pose_keys(p), j, p, t)
        for m, pose in posers.items():
            res = measure_poser(cfg, v, f, spec.body, body, pose)
            totals[m].append(res)
            print(f"{spec.types:28} {len(v):8d} {mean_edge_length(v, f) * 1e3:8.1f} {m:12} "
                  f"{res['inside_triangle_pct']:9.2f} {res['edge_error_mm']:11.2f}", flush=True)
    print(f"\nmean over {len(totals['baseline'])} outfits (score = inside % + edge mm, as the checkpoint choice "
          f"scores):")
    for m, rows in totals.items():
        mean = summarise(rows)
        print(f"{m:12} inside {mean['inside_triangle_pct']:.2f}%  edge {mean['edge_error_mm']:.2f} mm  "
              f"score {mean['score']:.3f}")


if __name__ == "__main__":
    main()
