"""How much of `drape eval layers`' RMSE comes from which way one chaotic simulation went?

Each held-out reference of `drape eval layers` is one two-layer simulation. Cloth in contact is chaotic: a change
in the last bits of the input sends a sequence another way (docs/sim.md, "Same bytes on every CPU": 1.8e-15 rad/s
made 6 mm RMS on dance_b). This re-simulates every combination x held-out motion of the evaluation with both
garments' rest vertices moved by a seeded random offset of PERTURB_M (1 micrometre, nothing a garment could show),
and measures the outer layer's RMSE against each simulation for the served networks and for DeePSD (each layer
rigged alone), as the evaluation does. It prints, per row, each simulation's RMSE and the difference drape - DeePSD
(negative: drape closer), then the spread: what a bar like "below DeePSD's" can read from one simulation.

Run: .venv/bin/python -m bench.layers_sim_spread [--variants 2]  (each variant ~2-3 min a sequence on one core;
the variants are cached under data/layers_spread/, the unperturbed ones are data/layers_eval/'s)
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.geometry.metrics import rmse_mm
from drape.runtime.engine import Engine
from drape.runtime.layers import LayerCombination, LayerTemplate
from drape.training import layers_eval as le

PERTURB_M = 1e-6
CACHE = Path("data") / "layers_spread"


def perturbed(c: LayerCombination, seed: int) -> LayerCombination:
    """c with both garments' rest vertices (N, 3) m moved by N(0, PERTURB_M) per coordinate (seeded)."""
    rng = np.random.default_rng([seed, 7])

    def moved(t: LayerTemplate) -> LayerTemplate:
        return replace(t, vertices=(t.vertices + rng.normal(0, PERTURB_M, t.vertices.shape)).astype(t.vertices.dtype))

    return replace(c, inner=moved(c.inner), outer=moved(c.outer))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", type=int, default=2, help="perturbed simulations per row, beside the evaluation's")
    args = ap.parse_args()
    engine = Engine(refine_workers=1)
    try:
        print(f"outer RMSE mm against each simulation (the evaluation's, then {args.variants} with rest vertices moved "
              f"by {PERTURB_M * 1e6:g} um): drape served / DeePSD each alone / drape - DeePSD")
        for c in engine.layers.combinations():
            body = load_body(c.inner.body)
            rows = le.Rows(engine, c)
            for motion in le.heldout_motions(body):
                sims = [le.simulated(c, motion, le.FRAMES, body)]
                for k in range(args.variants):
                    sims.append(le.simulated(perturbed(c, k), motion, le.FRAMES, body, cache=CACHE / f"v{k}"))
                poses, trans = sims[0]["poses"].astype(np.float64), sims[0]["trans"].astype(np.float64)
                served = rows.served(poses, trans, motion.fps)[1]
                deepsd = rows.deepsd(poses, trans)[1][1]
                ours = [rmse_mm(served, s["outer"]) for s in sims]
                theirs = [rmse_mm(deepsd, s["outer"]) for s in sims]
                diff = np.subtract(ours, theirs)
                apart = [rmse_mm(s["outer"], sims[0]["outer"]) for s in sims[1:]]
                print(f"{c.inner.name}+{c.outer.name} {motion.name}: "
                      + "  ".join(f"{o:.1f} / {t:.1f} / {d:+.1f}" for o, t, d in zip(ours, theirs, diff, strict=True))
                      + f"  | drape - DeePSD {diff.min():+.1f} .. {diff.max():+.1f} mm; the simulations "
                      + ", ".join(f"{a:.1f}" for a in apart) + " mm RMS from the evaluation's", flush=True)
    finally:
        engine.close()


if __name__ == "__main__":
    main()
