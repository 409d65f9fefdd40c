"""The refinement between layers pass by pass, on what drape serves (drape.geometry.layers.LayerRefiner).

For tshirt + jacket posed by the served layer networks along `drape eval layers`' held-out motions (60 frames of
dance_b and of the real CMU clip 02_01_walk, H_in 6.7 mm), the outer layer's L-Coll (behind the inner layer,
the simulation's measure) and H-Coll (inside the body, exact closest triangle) after each pass of the refiner:
the inner against the body, the outer against the body, the outer against the inner, the outer against the
body and the inner as one collider (the refiner's order); L-Coll always against the inner layer as refined by
the first pass. It shows what each pass costs the one before it; ms/frame: the whole refinement of a frame, one
process.

Run: .venv/bin/python -m bench.layers_refine_passes [--iterations 3]   (about 2 minutes on 2 cores)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drape.assets.body import load_body
from drape.geometry.layers import LayerRefiner, LayerReport
from drape.runtime.engine import Engine, posed_body
from drape.training import layers_eval as le

PASSES = ("posed", "outer vs body", "outer vs inner", "outer vs body and inner")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=3, help="the solver's max_iterations (the served default 3)")
    args = ap.parse_args()
    body = load_body("neutral")
    engine = Engine(refine_workers=1)
    try:
        c = engine.layers.find("tshirt", "jacket")
        rows = le.Rows(engine, c)
        print(f"tshirt + jacket ({c.model}), H_in {le.THICKNESS * 1e3:g} mm, {le.FRAMES} frames, "
              f"max_iterations {args.iterations}: outer L-Coll % / H-Coll % after each pass")
        print("| motion | " + " | ".join(PASSES) + " | ms/frame |\n| --- |" + " --: |" * (len(PASSES) + 1))
        for m in le.heldout_motions(body):
            poses, trans = m.poses[:le.FRAMES].astype(np.float64), m.trans[:le.FRAMES].astype(np.float64)
            inner, outer = rows.served(poses, trans, m.fps)
            r = LayerRefiner(c.inner.faces, c.inner.num_vertices, c.outer.faces, c.outer.num_vertices, le.THICKNESS,
                             body.faces, len(body.vertices), max_iterations=args.iterations)
            bodies = posed_body("neutral", poses, trans)
            stages: list[list[np.ndarray]] = [[] for _ in PASSES]
            inners, seconds = [], 0.0
            for i, o, b in zip(inner, outer, bodies, strict=True):
                passes = [o]
                t = time.perf_counter()
                i, _ = r.refine_frame(i, o, b, LayerReport(), stages=passes)
                seconds += time.perf_counter() - t
                for stage, x in zip(stages, passes, strict=True):
                    stage.append(x)
                inners.append(i)
            ri = np.stack(inners)
            cells = [f"{100 * le.l_coll(np.stack(s), ri, c.inner.faces)[0]:.2f} / "
                     f"{100 * le.h_coll(np.stack(s), bodies, body.faces):.2f}" for s in stages]
            print(f"| {m.name} | " + " | ".join(cells) + f" | {1e3 * seconds / len(inner):.0f} |", flush=True)
    finally:
        engine.close()


if __name__ == "__main__":
    main()
