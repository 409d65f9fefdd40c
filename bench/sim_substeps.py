"""Do more substeps keep the legs out of the skirt on the real CMU dances the intrinsic dataset's gate rejects?

Re-simulates items of an intrinsic dataset (by default `make intrinsic-data`'s: items its quality gate
rejected): each key `GARMENT__pNN__MOTION` names the garment mesh `DIR/GARMENT.obj`, the parameter set NN of
the dataset's manifest and the motion (`DIR/motions/MOTION.npz`, else the embedded clip of that name; an item
of any split, simulated or not), run for the dataset's frames with the set's `substeps` replaced by each value
of --substeps, and prints the gate's body penetration figures (p99 and max, mm; bars 5 and 30 mm), the share
of vertex-frames inside the body and the wall time. Needs the dataset's folder (git-ignored; its make target).
Run: .venv/bin/python -m bench.sim_substeps [--dataset DIR] [--items KEY ...] [--substeps 4 8 16]
  e.g. the long skirt's walk at 4 and 8 substeps (docs/sim.md "A long skirt"):
  .venv/bin/python -m bench.sim_substeps --dataset data/intrinsic/long_skirt --items long_skirt__p00__walk \
      --substeps 4 8
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from drape.assets.body import load_body
from drape.assets.motion import load_clip, load_motion_npz
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
    body = load_body(manifest["body"])
    print("item  substeps  penetration p99 mm  max mm  inside %  passes  s")
    for key in args.items:
        garment, p, motion_name = key.split("__")
        vertices, faces = load_mesh(root / f"{garment}.obj")
        params = SimParams(**manifest["params"][int(p[1:])])
        npz = root / "motions" / f"{motion_name}.npz"
        motion = load_motion_npz(npz, name=motion_name) if npz.exists() else load_clip(motion_name)
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
