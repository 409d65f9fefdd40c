"""What the served refinement costs per frame at about 6k vertices, timed against what it ran before the last
check and the surface's FAR_K were on, interleaved in the same run.

Input: the generated long sleeve + trousers at about 6k vertices (bench/refine_edges' case), rigged by the served
DeePSD rig and posed along the held-out clip dance_b, every 5th frame (31 frames). Variants, each refining every
frame once per pass, in an order that rotates between passes so that all see the same machine load:
- `before`: the relief pass, no last check (`verify_k=0`), a body surface without FAR_K: what /v1/refine and
  animate ran before;
- `/v1/refine`: the refinement's defaults (relief pass, last check, FAR_K): a stream with no rest shape;
- `animate`: the same with the outfit's rest shape (the edge-limit pass in the relief pass's place);
- `animate, no extra`: `animate` without the edge-limit pass's extra rounds (`stretch_extra=0`);
- `animate, cKDTree`: `animate` with the body's KD-tree from scipy (cKDTree, leaves of 32, unbalanced), what the
  refinement used before drape.geometry.nearest's pykdtree (same neighbours, bit-identical output).
Printed: ms per frame of each (median and range over the passes) and its ratio to `before` in the same pass. The
issue's bar is <= 25 ms per frame at 6k vertices in one process.

Run: .venv/bin/python -m bench.refine_cost [--passes 9] (about 1 minute on the 2-core machine)
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

import drape.geometry.refine as refine_module
from bench.refine_relief_cost import spread
from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.refine import FAR_K, BodySurface, Refiner, RefineReport
from drape.runtime.engine import Engine


class ScipyTree:
    """drape.geometry.nearest.VertexTree's interface on scipy's cKDTree (the refinement's tree before pykdtree)."""

    def __init__(self, vertices: np.ndarray):
        self.tree = cKDTree(vertices, leafsize=32, balanced_tree=False)

    def query(self, points: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        d, i = self.tree.query(points, k=k)
        return d.reshape(len(points), k), i.reshape(len(points), k)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--passes", type=int, default=9)
    args = ap.parse_args()
    engine, body = Engine(refine_workers=1), load_body("neutral")
    o = generate_outfit("longsleeve,trousers", vertices=6000, seed=77)
    clip = load_clip("dance_b")
    poses, trans = clip.poses.reshape(-1, 24, 3)[::5], clip.trans[::5]
    out = engine.rig(o.vertices, o.faces, "neutral")
    frames = np.concatenate(list(engine.pose_chunks(out, poses, trans))).astype(np.float64)
    bodies = body.pose(poses, trans).astype(np.float64)
    plain, served = (BodySurface(body.faces, len(body.vertices), far_k=k) for k in (None, FAR_K))
    n = len(o.vertices)
    variants = {"before": (Refiner(out.faces, n, verify_k=0), plain),
                "/v1/refine": (Refiner(out.faces, n), served),
                "animate": (Refiner(out.faces, n, rest=out.vertices), served),
                "animate, no extra": (Refiner(out.faces, n, rest=out.vertices, stretch_extra=0), served),
                "animate, cKDTree": (Refiner(out.faces, n, rest=out.vertices), served)}
    served_tree = refine_module.body_tree
    trees = {name: ScipyTree if name.endswith("cKDTree") else served_tree for name in variants}
    for name, (refiner, surface) in variants.items():  # warm up: first-call costs out of the timings
        refine_module.body_tree = trees[name]
        refiner.refine_frame(frames[0], bodies[0], surface, RefineReport())
    seconds = {name: np.zeros(args.passes) for name in variants}
    names = list(variants)
    for k in range(args.passes):
        order = names[k % len(names):] + names[:k % len(names)]
        for name in order:
            refiner, surface = variants[name]
            refine_module.body_tree = trees[name]
            t0 = time.perf_counter()
            for f, b in zip(frames, bodies, strict=True):
                refiner.refine_frame(f, b, surface, RefineReport())
            seconds[name][k] = time.perf_counter() - t0
    refine_module.body_tree = served_tree
    ms = {name: s / len(frames) * 1e3 for name, s in seconds.items()}
    print(f"N = {n}, {len(frames)} frames of dance_b, {args.passes} passes")
    print(f"{'variant':17s} {'ms/frame':>22s} {'/ before':>22s}")
    for name in names:
        print(f"{name:17s} {spread(ms[name]):>22s} {spread(ms[name] / ms['before']):>22s}")
    print(f"animate / animate, cKDTree: {spread(ms['animate'] / ms['animate, cKDTree'])}")
    print(f"animate / animate, no extra: {spread(ms['animate'] / ms['animate, no extra'])}")


if __name__ == "__main__":
    main()
