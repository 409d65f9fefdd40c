"""What a simulated sequence pays before its first step: MuJoCo compiling the scene, by cloth size.

A flex with bending (`elastic2d="both"`, drape's cloth) makes the compiler precompute per-edge bending
coefficients, and that cost grows much faster than the vertex count. `drape.sim.simulate.simulate_cloths` used to
compile the scene, then make its pinned top vertices heavy in `model.body_mass` and call `mj_setConst`, which
recomputes the bending coefficients too: a second compile's worth. It now sets those masses in the spec before
compiling (the model and the simulation are the same to the bit: `tests/sim/test_simulate.py`). This prints, per
cloth size (a generated long skirt; the body's collision hulls included, as in a dataset item): the compile, the
`mj_setConst` the old way paid on top, the same compile without bending (`elastic2d="stretch"`) as the reference,
and the stepping cost of one motion frame (`--substeps` steps from rest, the cloth falling onto the body) to put
them in scale, with and without bending: the per-step elasticity grows faster than the cloth too.

Run: .venv/bin/python -m bench.sim_setup [--vertices 1000 2000 3000] [--substeps 8]   (~3 min on the 2-core machine)
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from drape.assets.body import load_body
from drape.assets.outfits import generate_outfit
from drape.sim.collider import fit_hulls, garment_bones
from drape.sim.params import SimParams
from drape.sim.simulate import Cloth, scene_xml


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, nargs="+", default=[1000, 2000, 3000])
    ap.add_argument("--substeps", type=int, default=8)
    args = ap.parse_args()
    body = load_body("neutral")
    print(f"long skirt (seed 3, length 0.5) on the neutral body, {args.substeps} substeps; seconds")
    print("| vertices | compile | mj_setConst (the old second pass) | compile without bending | one frame of steps "
          "| the same without bending |")
    print("| --: | --: | --: | --: | --: | --: |")
    for n in args.vertices:
        outfit = generate_outfit(["long_skirt"], vertices=n, seed=3, length=0.5)
        v, f = outfit.vertices.astype(np.float64), outfit.faces
        hulls = fit_hulls(body, garment_bones(body, outfit.vertices, reach=0.2))
        xml = scene_xml([(Cloth("cloth", v, f), v)], hulls, SimParams(substeps=args.substeps), 30.0)
        t = time.perf_counter()
        model = mujoco.MjModel.from_xml_string(xml)
        compile_s = time.perf_counter() - t
        data = mujoco.MjData(model)
        t = time.perf_counter()
        mujoco.mj_setConst(model, data)
        setconst_s = time.perf_counter() - t
        t = time.perf_counter()
        stretch = mujoco.MjModel.from_xml_string(xml.replace('elastic2d="both"', 'elastic2d="stretch"'))
        stretch_s = time.perf_counter() - t
        frame_s = [_frame(m, mujoco.MjData(m), args.substeps) for m in (model, stretch)]
        print(f"| {len(v):,} | {compile_s:.1f} | {setconst_s:.1f} | {stretch_s:.2f} | {frame_s[0]:.2f} | "
              f"{frame_s[1]:.2f} |")


def _frame(model, data, substeps: int) -> float:
    """Seconds of one motion frame's steps (the second frame from rest)."""
    for _ in range(substeps):
        mujoco.mj_step(model, data)
    t = time.perf_counter()
    for _ in range(substeps):
        mujoco.mj_step(model, data)
    return time.perf_counter() - t


if __name__ == "__main__":
    main()
