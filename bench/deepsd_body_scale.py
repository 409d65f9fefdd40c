"""Does DeePSD rig garments on bodies outside its trained heights better when it reads them scaled into that
range (drape.geometry.body_scale)? On the VALIDATION split only (never the held-out table, whose unseen body
is the `heavy` preset): three bodies made here by scaling the trained presets past their heights (1.66-1.80 m)
- `val_tall` (neutral x 1.12: 1.88 m), `val_short` (female x 0.90: 1.50 m) and `val_big` (male x 1.15 across,
x 1.08 up: 1.94 m, wider, like a heavier body) - none of them `heavy` or a preset. On each, the config's
validation outfits (its outfit types and seeds, generated on that body) along its validation motions
(procedural and real CMU, imported onto that body), measured as the checkpoint choice measures them
(drape.training.deepsd_validation.measure_poser: inside % by closest triangle, edge error mm; the 4-influence
served rig), for: the nearest-body-weights baseline, the shipped model reading the garment as it is
(`scale_bodies=None`) and scaled (the default).

Run: .venv/bin/python -m bench.deepsd_body_scale [--config CONFIG] [--bodies val_tall,val_big]
(about 25 minutes on the 2-core machine for the three bodies).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from drape.assets.body import Body, load_body, register_body
from drape.geometry.body_scale import body_height
from drape.geometry.lbs import pose_mesh
from drape.geometry.queries import nearest_vertex_weights
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, pose_outfit
from drape.runtime.sparse_rig import fit_poses, sparse_rig
from drape.training.deepsd_data import load_outfit
from drape.training.deepsd_validation import measure_poser, summarise, validation_specs

# name -> (preset, scale along x, y, z)
BODIES = {"val_tall": ("neutral", (1.12, 1.12, 1.12)), "val_short": ("female", (0.90, 0.90, 0.90)),
          "val_big": ("male", (1.15, 1.08, 1.15))}


def scaled_body(name: str) -> Body:
    """One of BODIES, registered so that outfits and motions can be made on it by name."""
    preset, s = BODIES[name]
    b = load_body(preset)
    scale = np.asarray(s, dtype=np.float32)
    body = Body(name, b.vertices * scale, b.faces, b.weights, b.joints * scale, b.parents, b.joint_names)
    register_body(body)
    return body


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="drape/training/configs/deepsd_candidates_loose_prior.json")
    parser.add_argument("--bodies", default=",".join(BODIES))
    parser.add_argument("--models", default="as_is,height,torso", help="as_is: scale_bodies=None; height, torso: "
                        "DeePSDModel's scale_bodies")
    args = parser.parse_args()
    with open(args.config) as fh:
        cfg = json.load(fh)
    models = {m: DeePSDModel(MODEL_DIR, scale_bodies=None if m == "as_is" else m) for m in args.models.split(",")}
    shipped = DeePSDModel(MODEL_DIR)
    print(f"DeePSD {shipped.manifest['version']}, trained heights {shipped.trained_heights}; validation of "
          f"{args.config}")
    poses_fit = fit_poses()
    keys_fit = shipped.pose_keys(poses_fit)
    influences = cfg["validation"]["influences"]
    totals: dict[str, list[dict]] = {"baseline": [], **{m: [] for m in models}}
    for name in args.bodies.split(","):
        body = scaled_body(name)
        scales = {m: model.body_scale(body) for m, model in models.items()}
        print(f"\n{name}: {body_height(body.vertices):.3f} m, read at scale (x, y, z) "
              + ", ".join(f"{m} {[1.0, 1.0, 1.0] if s is None else s.scale.round(3).tolist()}" for m, s in scales.items()))
        print(f"{'outfit':28} {'method':9} {'inside %':>9} {'edge mm':>8}")
        for spec in validation_specs(cfg):
            spec = replace(spec, body=name)
            v, f = load_outfit(spec)
            posers: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {}
            w, joints = nearest_vertex_weights(v, body.vertices, body.weights), body.joints
            posers["baseline"] = lambda p, t, w=w, v=v, j=joints: pose_mesh(v, w, j, p, t)
            for m, model in models.items():
                r = sparse_rig(v, model.rig(v, f, body), body.joints, influences, poses_fit, keys_fit)
                posers[m] = lambda p, t, r=r, v=v, j=joints, model=model: pose_outfit(v, r, model.pose_keys(p), j, p, t)
            for m, pose in posers.items():
                res = measure_poser(cfg, v, f, name, body, pose)
                totals[m].append(res)
                print(f"{spec.types:28} {m:9} {res['inside_triangle_pct']:9.2f} {res['edge_error_mm']:8.2f}",
                      flush=True)
    print(f"\nmean over {len(totals['baseline'])} outfit x body pairs (score = inside % + edge mm, as the "
          f"checkpoint choice scores):")
    for m, rows in totals.items():
        mean = summarise(rows)
        print(f"{m:9} inside {mean['inside_triangle_pct']:.2f}%  edge {mean['edge_error_mm']:.2f} mm  "
              f"score {mean['score']:.3f}")


if __name__ == "__main__":
    main()
