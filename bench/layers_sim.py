"""Two layers from DeePSD against the two-layer simulation, on motions DeePSD never trained on.

Ground truth: drape.sim.layers.simulate_layers (MuJoCo; the outer colliding with the inner and the body) of
two layered outfits (tshirt + jacket, tanktop + longsleeve; 4,000 vertices together, split from one generated
outfit) at H_in = 6 mm along the held-out clip dance_b and the real CMU clip 02_01_walk (30 fps; skipped
without ../shared/data/mocap), FRAMES frames each. The simulations are cached under data/layers_eval/
(git-ignored; delete it to simulate again).

Rows, each against the simulation's frames of the same motion: `one outfit` (DeePSD rigs both layers as one
outfit: today's way), `each alone` (each layer rigged on its own), `+ body` (each refined against the body) and
`+ layers` (drape.geometry.layers: then the outer against the inner, H_in); `sim` gives the simulation's own
collision figures. Columns: the outer layer's RMSE and Hausdorff (mm) and STED against the simulation; H-Coll
of inner and outer (share of vertices inside the body, exact closest triangle); L-Coll (outer vertices behind
the inner layer within 2 cm where it covers them: drape.sim.quality.outer_inner_distance).

Run: .venv/bin/python -m bench.layers_sim [--frames 60] (about 10 minutes on 2 cores, 2 of them simulating)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import Motion, import_motion, load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.layers import LayerRefiner, LayerReport
from drape.geometry.metrics import hausdorff_mm, rmse_mm, sted
from drape.geometry.queries import signed_distance_to_mesh
from drape.geometry.refine import BodySurface, Refiner, RefineReport
from drape.runtime.engine import Engine
from drape.sim.layers import simulate_layers, split_outfit
from drape.sim.params import LayerParams
from drape.sim.quality import INSIDE_BAND, outer_inner_distance

PAIRS = ("tshirt,jacket", "tanktop,longsleeve")
VERTICES = 4000
SEED = 7
THICKNESS = 0.006
REAL = Path("..") / "shared" / "data" / "mocap" / "02_01_walk.bvh"
CACHE = Path("data") / "layers_eval"


def motions(body) -> list[Motion]:  # noqa: ANN001
    out = [load_clip("dance_b")]
    if REAL.exists():
        out.append(import_motion(REAL.read_bytes(), body, fps=30.0, name=REAL.stem).motion)
    return out


def simulated(pair: str, motion: Motion, frames: int, inner, outer, body) -> dict:  # noqa: ANN001
    """The two-layer simulation (cached): inner (T, Ni, 3), outer (T, No, 3), poses, trans, stats."""
    path = CACHE / f"{pair.replace(',', '+')}_{motion.name}_{frames}.npz"
    if not path.exists():
        r = simulate_layers(*inner, *outer, body, motion, LayerParams(inner_thickness=THICKNESS), frames=frames)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, inner=r.inner_vertices, outer=r.outer_vertices, poses=r.poses, trans=r.trans,
                 seconds_per_frame=r.seconds_per_frame)
    z = np.load(path)
    return {k: z[k] for k in z.files}


def h_coll(frames: np.ndarray, bodies: np.ndarray, faces: np.ndarray) -> float:
    return float(np.mean([np.mean(signed_distance_to_mesh(x, b, faces) < 0) for x, b in zip(frames, bodies, strict=True)]))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=60, help="motion frames simulated per sequence")
    args = ap.parse_args()
    engine = Engine(refine_workers=1)
    body = load_body("neutral")
    surface = BodySurface(body.faces, len(body.vertices))
    print(f"{'pair':19s} {'clip':11s} {'T':>3s} {'rows':11s} {'RMSE mm':>8s} {'Haus mm':>8s} {'STED':>6s} "
          f"{'H inner':>8s} {'H outer':>8s} {'L-Coll':>7s}")
    for pair in PAIRS:
        (vi, fi), (vo, fo) = split_outfit(pair, VERTICES, seed=SEED)
        whole = generate_outfit(pair.split(","), vertices=VERTICES, seed=SEED)
        rigs = [engine.rig(v, f, "neutral") for v, f in ((whole.vertices, whole.faces), (vi, fi), (vo, fo))]
        layers = LayerRefiner(fi, len(vi), fo, len(vo), THICKNESS, body.faces, len(body.vertices))
        body_i, body_o = Refiner(fi, len(vi)), Refiner(fo, len(vo))
        for motion in motions(body):
            sim = simulated(pair, motion, args.frames, (vi, fi), (vo, fo), body)
            poses, trans = sim["poses"].astype(np.float64), sim["trans"].astype(np.float64)
            bodies = body.pose(poses, trans).astype(np.float64)
            w, gi, go = [np.concatenate(list(engine.pose_chunks(r, poses, trans))).astype(np.float64) for r in rigs]
            r = RefineReport()
            bi = np.stack([body_i.refine_frame(x, b, surface, r) for x, b in zip(gi, bodies, strict=True)])
            bo = np.stack([body_o.refine_frame(x, b, surface, r) for x, b in zip(go, bodies, strict=True)])
            report = LayerReport()
            both = [layers.refine_frame(i, o, b, report) for i, o, b in zip(gi, go, bodies, strict=True)]
            rows = {"sim": (sim["inner"], sim["outer"]),
                    "one outfit": (w[:, whole.garment == 0], w[:, whole.garment == 1]),
                    "each alone": (gi, go), "+ body": (bi, bo),
                    "+ layers": (np.stack([p[0] for p in both]), np.stack([p[1] for p in both]))}
            for label, (inner, outer) in rows.items():
                sd, covered = outer_inner_distance(outer, inner, fi)
                lcoll = float(np.mean(covered & (sd < 0) & (sd >= -INSIDE_BAND)))
                if label == "sim":
                    err = f"{'':8s} {'':8s} {'':6s}"
                else:
                    err = (f"{rmse_mm(outer, sim['outer']):8.1f} {hausdorff_mm(outer, sim['outer']):8.1f} "
                           f"{sted(outer, sim['outer'], fo)['sted']:6.3f}")
                print(f"{pair:19s} {motion.name[:11]:11s} {len(bodies):3d} {label:11s} {err} "
                      f"{h_coll(inner, bodies, body.faces):8.2%} {h_coll(outer, bodies, body.faces):8.2%} "
                      f"{lcoll:7.2%}", flush=True)


if __name__ == "__main__":
    main()
