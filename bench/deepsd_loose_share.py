"""Does moving a loose dress's rig weights onto the pelvis trade stretch for collisions? On the VALIDATION
split only (the config's validation dress and motions, never the held-out table), the shipped DeePSD rig of
the validation dress, and the same rig with `share` of each loose vertex's weights (beyond the config's
`joint_candidates.loose_beyond`, drape.geometry.queries.loose_points) moved onto the lowest common ancestor of
its candidate joints (drape.training.deepsd_data.loose_ancestor_prior applied to the rig's weights instead of
the prior), its blend shapes unchanged. Dense rig (no 4-influence refit), so the rows compare weights only.

Prints per share: inside % (closest triangle) and edge error mm, as the validation measures them
(drape.training.deepsd_validation.measure_poser), and the mean pelvis weight of the loose vertices.
Run: .venv/bin/python -m bench.deepsd_loose_share [--config CONFIG] [--outfit dress]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

from drape.assets.body import load_body
from drape.geometry.queries import CANDIDATE_STRIDE, candidate_joints, loose_points
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, pose_outfit
from drape.training.deepsd_data import load_outfit, loose_ancestor_prior
from drape.training.deepsd_validation import measure_poser, validation_specs

SHARES = (0.0, 0.25, 0.5, 0.75, 1.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="drape/training/configs/deepsd_candidates_loose_prior.json")
    parser.add_argument("--outfit", default="dress", help="a validation outfit type of the config")
    args = parser.parse_args()
    with open(args.config) as fh:
        cfg = json.load(fh)
    spec = next(s for s in validation_specs(cfg) if s.types == args.outfit)
    v, f = load_outfit(spec)
    body = load_body(spec.body)
    model = DeePSDModel(MODEL_DIR)
    rig = model.rig(v, f, body)
    cand = cfg["joint_candidates"]
    mask = candidate_joints(v, body.vertices, body.weights, parents=body.parents, **cand)
    loose = loose_points(v, body.vertices, cand["loose_beyond"], cand.get("stride", CANDIDATE_STRIDE))
    pelvis = body.joint_names.index("pelvis")
    print(f"{spec.key}: {len(v)} vertices, {loose.sum()} loose (beyond {cand['loose_beyond'] * 100:.0f} cm); "
          f"DeePSD {model.manifest['version']}, validation motions of {args.config}")
    print("share  inside %  edge mm  loose pelvis weight")
    for share in SHARES:
        weights = loose_ancestor_prior(rig.weights, mask, loose, body.parents, share)
        r = replace(rig, weights=weights)
        m = measure_poser(cfg, v, f, spec.body, body, lambda p, t, r=r: pose_outfit(v, r, model.pose_keys(p),
                                                                                     body.joints, p, t))
        print(f"{share:5.2f}  {m['inside_triangle_pct']:8.2f}  {m['edge_error_mm']:7.2f}  "
              f"{weights[loose, pelvis].mean():.3f}")


if __name__ == "__main__":
    main()
