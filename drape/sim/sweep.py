"""`drape sim sweep`: find the parameter ranges the way Wang et al. 2019 (Sec. 3.6) do.

Starting from the base `SimParams()`, one parameter at a time is set to each
value of a wide grid while the others stay at the base; every run simulates the
same knee-length skirt on the neutral body along the start of the walk clip and
records whether it passes the quality gate, plus the mean garment height above
the root (how low the cloth hangs), the mean edge strain and the penetration.
The sampler's ranges (`params.SAMPLE_RANGES`) keep inside the values that
passed and looked like cloth; docs/sim.md has the table.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from drape.sim.params import SimParams

GRID: dict[str, list[float]] = {
    "young": [1e4, 3e4, 1e5, 3e5, 1e6, 3e6, 1e7],
    "poisson": [0.0, 0.1, 0.3, 0.45, 0.49],
    "thickness": [2e-4, 5e-4, 1e-3, 2e-3, 5e-3],
    "density": [0.05, 0.1, 0.2, 0.4, 1.0],
    "damping": [0.0, 2e-5, 1e-4, 5e-4, 2e-3],
    "gravity": [3.0, 7.0, 9.81, 12.0, 20.0],
    "air_drag": [0.0, 0.5, 2.0, 5.0, 20.0],
}


def _one(job: tuple[str, float, int, int]) -> dict:
    from drape.assets.body import load_body
    from drape.assets.motion import load_clip
    from drape.assets.outfits import generate_outfit
    from drape.sim.quality import QualityGate
    from drape.sim.simulate import simulate

    name, value, frames, vertices = job
    outfit = generate_outfit("skirt", vertices=vertices, seed=3, length=0.6)
    params = SimParams(**{**SimParams().model_dump(), name: value})
    r = simulate(outfit.vertices, outfit.faces, load_body("neutral"), load_clip("walk"), params, frames=frames)
    keep = ("penetration_p99_m", "penetration_max_m", "strain_mean", "strain_p99", "mean_height_m",
            "seconds_per_frame", "finite")
    return {"param": name, "value": value, "failures": QualityGate().failures(r.stats),
            **{k: r.stats[k] for k in keep if k in r.stats}}


def run_sweep(out: str | Path, workers: int | None = None, frames: int = 45, vertices: int = 1200) -> list[dict]:
    """Run the grid, write JSON rows to `out`, print a table; returns the rows."""
    jobs = [(name, float(v), frames, vertices) for name, values in GRID.items() for v in values]
    with ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
        rows = list(pool.map(_one, jobs))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps({"base": SimParams().model_dump(), "frames": frames, "vertices": vertices,
                                     "clip": "walk", "rows": rows}, indent=1))
    print(f"{'param':>10} {'value':>9} {'gate':>5} {'height m':>9} {'strain':>7} {'pen p99 mm':>10} {'pen max mm':>10}")
    for r in rows:
        finite = r.get("finite", False)
        print(f"{r['param']:>10} {r['value']:>9.3g} {'ok' if not r['failures'] else 'FAIL':>5} "
              f"{r.get('mean_height_m', float('nan')) if finite else float('nan'):>9.4f} "
              f"{r.get('strain_mean', float('nan')):>7.4f} {1000 * r.get('penetration_p99_m', float('nan')):>10.2f} "
              f"{1000 * r.get('penetration_max_m', float('nan')):>10.2f}")
    return rows
