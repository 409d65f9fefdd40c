"""How far the served rig (at most k skin influences a vertex) poses from the network's dense rig, on
held-out clips, with and without the blend-shape refit of drape.runtime.sparse_rig; and what the fit costs.

For each outfit (held-out seeds) and k in (4, 8): the plain top-k rig (weights renormalised, blend
shapes unchanged) and the served rig (top-k + refit blend shapes) are posed along the clips DeePSD held
out of training (walk, kick, dance_b) beside the dense rig; prints the mean and max per-vertex distance
(mm) from the dense rig's posed vertices, the ratio served / plain, and the fit's seconds.
Run: .venv/bin/python -m bench.sparse_rig [--vertices 6000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.runtime.deepsd import DeePSDModel, Rig, pose_outfit
from drape.runtime.sparse_rig import fit_poses, sparse_rig, top_weights

HELD_OUT = ("walk", "kick", "dance_b")
OUTFITS = ("tshirt,trousers", "dress", "longsleeve,shorts", "skirt")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--vertices", type=int, default=6000)
    args = p.parse_args()
    model, body = DeePSDModel(), load_body("neutral")
    fit = fit_poses()
    fit_keys = model.pose_keys(fit)
    print(f"distance from the dense rig, mm (mean / max over vertices and frames), clips {', '.join(HELD_OUT)}")
    print(f"{'outfit':18s} {'k':>2s} {'plain mean':>10s} {'plain max':>9s} {'served mean':>11s} {'served max':>10s}"
          f" {'served/plain':>12s} {'fit s':>6s}")
    for i, spec in enumerate(OUTFITS):
        o = generate_outfit(spec, vertices=args.vertices, seed=91000 + i)
        dense = model.rig(o.vertices, o.faces, body)
        for k in (4, 8):
            t = time.perf_counter()
            served = sparse_rig(o.vertices, dense, body.joints, k, fit, fit_keys)
            fit_s = time.perf_counter() - t
            plain = Rig(top_weights(dense.weights, k), dense.blend_shapes)
            err: dict[str, list[np.ndarray]] = {"plain": [], "served": []}
            for clip in HELD_OUT:
                m = load_clip(clip)
                keys = model.pose_keys(m.poses)
                ref = pose_outfit(o.vertices, dense, keys, body.joints, m.poses, m.trans)
                for name, rig in (("plain", plain), ("served", served)):
                    out = pose_outfit(o.vertices, rig, keys, body.joints, m.poses, m.trans)
                    err[name].append(np.linalg.norm(out - ref, axis=2).ravel() * 1e3)
            pl, sv = np.concatenate(err["plain"]), np.concatenate(err["served"])
            print(f"{spec:18s} {k:2d} {pl.mean():10.2f} {pl.max():9.1f} {sv.mean():11.2f} {sv.max():10.1f}"
                  f" {sv.mean() / pl.mean():12.2f} {fit_s:6.2f}")


if __name__ == "__main__":
    main()
