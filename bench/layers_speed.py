"""How long posing both layers takes at the size issue 22's bar names (a ~3k inner + a ~5k outer, 300 frames).

The served combinations are smaller (tshirt + jacket: 1,520 + 2,380 vertices). The layer networks' ONNX graphs do
not depend on the template's size (they give basis coefficients: 64 keys for the inner, 128 for the outer); the
vertices come from the batched posing of a rig (blend shapes (K, N, 3) + skinning), which does. So this poses a
larger tshirt + jacket (`split_outfit` at 8,000 vertices together, seed 7) through the served path
(`Engine.layer_chunks`, no refine) with the shipped networks' graphs and rigs carried over to it: each blend
shape of a network's basis moved to the larger template by nearest rest vertex, the skin weights DeePSD's served
rig of the larger template. The vertices it gives are not a trained model of that template (none ships); the
seconds are what serving one would cost. Baseline in the same run: DeePSD's served rigs of the two layers alone
(what `/v1/layers/animate` falls back to), and both at the served size.

Output: seconds to pose 300 frames of both layers (DeepMimic dance_b, tiled), best of 3, and the ratio to
DeePSD's at the same size.

Run: .venv/bin/python -m bench.layers_speed [--vertices 8000]   (about 20 s on the 2-core machine)
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
from scipy.spatial import cKDTree

from drape.assets.motion import load_clip
from drape.assets.outfits import split_outfit
from drape.runtime.deepsd import Rig
from drape.runtime.engine import Engine
from drape.runtime.layers import BODY, SEED, LayerCombination, LayerTemplate

FRAMES = 300
THICKNESS = 0.0067


def carried(network, vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray):
    """A copy of a layer network (InnerModel / OuterModel) posing another template: its basis (K, N, 3) moved to
    `vertices` (M, 3) by nearest rest vertex, skin weights (M, 24) given."""
    nearest = cKDTree(network.vertices).query(vertices)[1]
    out = copy.copy(network)
    out.vertices, out.faces = vertices, faces
    out.rig = Rig(weights=np.asarray(weights, np.float32), blend_shapes=network.rig.blend_shapes[:, nearest])
    return out


def best_of(fn, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=8000, help="both layers together, larger than the served 4,000")
    args = ap.parse_args()
    clip = load_clip("dance_b")
    reps = -(-FRAMES // clip.num_frames)
    poses = np.tile(clip.poses, (reps, 1, 1))[:FRAMES]
    trans = np.tile(clip.trans, (reps, 1))[:FRAMES]
    engine = Engine(refine_workers=1)
    try:
        served = engine.layers.find("tshirt", "jacket")
        if served is None or served.inner.network is None or served.outer.network is None:
            raise SystemExit("the tshirt + jacket layer networks are not served")
        (vi, fi), (vo, fo) = split_outfit("tshirt,jacket", args.vertices, seed=SEED, body=BODY)
        rig_i, rig_o = engine.rig(vi, fi, BODY), engine.rig(vo, fo, BODY)
        large = LayerCombination(
            LayerTemplate("tshirt", "inner", BODY, vi, fi, carried(served.inner.network, vi, fi, rig_i.rig.weights)),
            LayerTemplate("jacket", "outer", BODY, vo, fo, carried(served.outer.network, vo, fo, rig_o.rig.weights)),
            served.thickness)
        small = (engine.rig(served.inner.vertices, served.inner.faces, BODY),
                 engine.rig(served.outer.vertices, served.outer.faces, BODY))

        def layers(c: LayerCombination) -> None:
            for _ in engine.layer_chunks(c, THICKNESS, poses, trans, fps=clip.fps):
                pass

        def deepsd(rigs) -> None:
            for r in rigs:
                for _ in engine.pose_chunks(r, poses, trans):
                    pass

        print(f"{FRAMES} frames of both layers (dance_b tiled), no refine, best of 3, seconds:")
        print("| layers | inner + outer vertices | layer networks (served path) | DeePSD's two rigs | ratio |")
        print("| --- | --: | --: | --: | --: |")
        for label, c, rigs in (("served tshirt + jacket", served, small),
                               ("larger tshirt + jacket (networks carried over)", large, (rig_i, rig_o))):
            a, b = best_of(lambda c=c: layers(c)), best_of(lambda rigs=rigs: deepsd(rigs))
            print(f"| {label} | {c.inner.num_vertices:,} + {c.outer.num_vertices:,} | {a:.3f} | {b:.3f} | "
                  f"{a / b:.1f}x |")
    finally:
        engine.close()


if __name__ == "__main__":
    main()
