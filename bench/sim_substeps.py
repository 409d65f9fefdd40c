"""Do more substeps keep the legs out of the skirt on the real CMU dances the intrinsic dataset's gate rejects?

Re-simulates items of `make intrinsic-data`'s dataset that the quality gate rejected (their parameter set,
motion and frames from the dataset's manifest and rejected/ folder) with the parameter set's `substeps`
replaced by each value of --substeps (the first, 4, is what the dataset used), and prints the gate's body
penetration figures (p99 and max, mm; bars 5 and 30 mm), the share of vertex-frames inside the body and
the wall time. Needs data/intrinsic/skirt (git-ignored; `make intrinsic-data`).
Run: .venv/bin/python -m bench.sim_substeps [--dataset DIR] [--items KEY ...] [--substeps 4 8 16]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from drape.assets.body import load_body
from drape.assets.motion import load_motion_npz
from drape.geometry.mesh_io import load_mesh
from drape.sim.params import SimParams
from drape.sim.quality import QualityGate
from drape.sim.simulate import simulate

DEFAULT_ITEMS = ("skirt__p09__cmu_05_06_dance", "skirt__p10__cmu_05_08_dance", "skirt__p06__cmu_05_07_dance")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="data/intrinsic/skirt")
    parser.add_argument("--items", nargs="+", default=list(DEFAULT_ITEMS), help="rejected item keys")
    parser.add_argument("--substeps", nargs="+", type=int, default=[4, 8, 16])
    args = parser.parse_args()
    root = Path(args.dataset)
    manifest = json.loads((root / "manifest.json").read_text())
    gate = QualityGate(**manifest["gate"])
    vertices, faces = load_mesh(root / "skirt.obj")
    body = load_body(manifest["body"])
    print("item  substeps  penetration p99 mm  max mm  inside %  passes  s")
    for key in args.items:
        _, p, motion_name = key.split("__")
        params = SimParams(**manifest["params"][int(p[1:])])
        motion = load_motion_npz(root / "motions" / f"{motion_name}.npz", name=motion_name)
        for substeps in args.substeps:
            t0 = time.perf_counter()
            r = simulate(vertices, faces, body, motion, params.model_copy(update={"substeps": substeps}),
                         frames=int(manifest["frames"]))
            s = r.stats
            fails = gate.failures(s)
            print(f"{key}  {substeps:3d}  {1e3 * s['penetration_p99_m']:6.2f}  {1e3 * s['penetration_max_m']:6.1f}  "
                  f"{100 * s['inside_share']:5.2f}  {'yes' if not fails else 'no'}  {time.perf_counter() - t0:6.1f}",
                  flush=True)


if __name__ == "__main__":
    main()
