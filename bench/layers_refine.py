"""Two layers from DeePSD, and the refinement between layers (drape.geometry.layers).

Inputs: two layered outfits (tshirt + jacket, tanktop + longsleeve; 4,000 vertices together, generated as one
outfit and split: drape.sim.layers.split_outfit) on the neutral body, along the held-out clip dance_b and the
real CMU clip 02_01_walk (imported at 30 fps; skipped where ../shared/data/mocap is absent), every EVERY-th
frame. Rows, per pair and clip:
- `one outfit`: DeePSD rigs both layers as one outfit (today's way), served rig (4 influences);
- `each alone`: DeePSD rigs each layer on its own;
- `+ body`: each alone, each layer refined against the body (drape.geometry.refine, what animate does today);
- `+ layers`: each alone, refined against the body and then the outer against the inner (LayerRefiner, H_in).
Columns: H-Coll of the inner and the outer (share of vertices inside the body, exact closest triangle), L-Coll
(share of outer vertices behind the inner layer, within 2 cm, where the inner covers them: the two-layer
simulation's measure, drape.sim.quality.outer_inner_distance), the outer's median gap to the inner (mm,
covered vertices), the edges made longer than 2x their rest length (count over frame-edges, both layers), and
the refinement's milliseconds per frame (both layers, this process).

Run: .venv/bin/python -m bench.layers_refine [--every 4] [--thickness 0.006] (about 5 minutes on 2 cores)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import import_motion, load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.layers import LayerRefiner, LayerReport
from drape.geometry.mesh import unique_edges
from drape.geometry.queries import signed_distance_to_mesh
from drape.geometry.refine import BodySurface, Refiner, RefineReport
from drape.runtime.engine import Engine
from drape.sim.layers import split_outfit
from drape.sim.quality import INSIDE_BAND, outer_inner_distance

PAIRS = ("tshirt,jacket", "tanktop,longsleeve")
VERTICES = 4000
SEED = 7
REAL = Path("..") / "shared" / "data" / "mocap" / "02_01_walk.bvh"


def clips(body, every: int):  # noqa: ANN001, ANN201
    """[(name, poses (T, 24, 3), translation (T, 3))]: dance_b and, where present, CMU 02_01_walk at 30 fps."""
    c = load_clip("dance_b")
    out = [("dance_b", c.poses.reshape(-1, 24, 3)[::every], c.trans[::every])]
    if REAL.exists():
        m = import_motion(REAL.read_bytes(), body, fps=30.0, name=REAL.stem).motion
        out.append((REAL.stem, m.poses.reshape(-1, 24, 3)[::every], m.trans[::every]))
    return out


def new_long_edges(frames: np.ndarray, posed: np.ndarray, rest: np.ndarray, faces: np.ndarray) -> int:
    """Edges longer than 2x their rest length in `frames` (T, N, 3) that were not in `posed` (the unrefined
    input), counted over frame-edges."""
    e = unique_edges(faces)
    r = np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)
    before = np.linalg.norm(posed[:, e[:, 0]] - posed[:, e[:, 1]], axis=2) / r
    after = np.linalg.norm(frames[:, e[:, 0]] - frames[:, e[:, 1]], axis=2) / r
    return int(np.count_nonzero((after > 2) & (before <= 2)))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--every", type=int, default=4, help="use every k-th frame")
    ap.add_argument("--thickness", type=float, default=0.006, help="the inner layer's thickness H_in, m")
    args = ap.parse_args()
    engine = Engine(refine_workers=1)
    body = load_body("neutral")
    surface = BodySurface(body.faces, len(body.vertices))
    print(f"{'pair':19s} {'clip':11s} {'T':>4s} {'rows':12s} {'H inner':>8s} {'H outer':>8s} {'L-Coll':>7s} "
          f"{'gap mm':>7s} {'new >2x':>7s} {'ms/frame':>8s}")
    for pair in PAIRS:
        (vi, fi), (vo, fo) = split_outfit(pair, VERTICES, seed=SEED)
        whole = generate_outfit(pair.split(","), vertices=VERTICES, seed=SEED)
        layer = whole.garment
        rig_whole = engine.rig(whole.vertices, whole.faces, "neutral")
        rig_i, rig_o = engine.rig(vi, fi, "neutral"), engine.rig(vo, fo, "neutral")
        refiner = LayerRefiner(fi, len(vi), fo, len(vo), args.thickness, body.faces, len(body.vertices))
        body_i, body_o = Refiner(fi, len(vi)), Refiner(fo, len(vo))
        for name, poses, trans in clips(body, args.every):
            bodies = body.pose(poses, trans).astype(np.float64)

            w, *alone = [np.concatenate(list(engine.pose_chunks(rig, poses, trans))).astype(np.float64)
                         for rig in (rig_whole, rig_i, rig_o)]
            rows = {"one outfit": ((w[:, layer == 0], w[:, layer == 1]), 0.0)}
            rows["each alone"] = (alone, 0.0)
            t = time.perf_counter()
            r = RefineReport()
            refined = (np.stack([body_i.refine_frame(x, b, surface, r) for x, b in zip(alone[0], bodies, strict=True)]),
                       np.stack([body_o.refine_frame(x, b, surface, r) for x, b in zip(alone[1], bodies, strict=True)]))
            rows["+ body"] = (refined, (time.perf_counter() - t) / len(bodies))
            t = time.perf_counter()
            report = LayerReport()
            pairs = [refiner.refine_frame(i, o, b, report) for i, o, b in zip(*alone, bodies, strict=True)]
            rows["+ layers"] = ((np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])),
                                (time.perf_counter() - t) / len(bodies))
            for label, ((inner, outer), seconds) in rows.items():
                h = [np.mean([np.mean(signed_distance_to_mesh(x, b, body.faces) < 0) for x, b in
                              zip(layer_frames, bodies, strict=True)]) for layer_frames in (inner, outer)]
                sd, covered = outer_inner_distance(outer, inner, fi)
                lcoll = float(np.mean(covered & (sd < 0) & (sd >= -INSIDE_BAND)))
                gap = float(np.median(sd[covered])) * 1e3
                longer = (new_long_edges(inner, alone[0], vi, fi) + new_long_edges(outer, alone[1], vo, fo)
                          if label.startswith("+") else 0)
                print(f"{pair:19s} {name:11s} {len(bodies):4d} {label:12s} {h[0]:8.2%} {h[1]:8.2%} {lcoll:7.2%} "
                      f"{gap:7.1f} {longer:7d} {seconds * 1e3:8.1f}", flush=True)


if __name__ == "__main__":
    main()
