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

from bench.layers_refine import PAIRS, REAL, LayerRows, h_coll, l_coll
from drape.assets.body import load_body
from drape.assets.motion import Motion, import_motion, load_clip
from drape.geometry.metrics import hausdorff_mm, rmse_mm, sted
from drape.geometry.refine import BodySurface
from drape.runtime.engine import Engine
from drape.sim.layers import simulate_layers
from drape.sim.params import LayerParams

THICKNESS = 0.006
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
        lr = LayerRows(engine, pair, THICKNESS, body, surface)
        for motion in motions(body):
            sim = simulated(pair, motion, args.frames, (lr.vi, lr.fi), (lr.vo, lr.fo), body)
            poses, trans = sim["poses"].astype(np.float64), sim["trans"].astype(np.float64)
            bodies = body.pose(poses, trans).astype(np.float64)
            rows = {"sim": (sim["inner"], sim["outer"]),
                    **{label: frames for label, (frames, _) in lr.rows(poses, trans, bodies).items()}}
            for label, (inner, outer) in rows.items():
                lcoll = l_coll(outer, inner, lr.fi)[0]
                if label == "sim":
                    err = f"{'':8s} {'':8s} {'':6s}"
                else:
                    err = (f"{rmse_mm(outer, sim['outer']):8.1f} {hausdorff_mm(outer, sim['outer']):8.1f} "
                           f"{sted(outer, sim['outer'], lr.fo)['sted']:6.3f}")
                print(f"{pair:19s} {motion.name[:11]:11s} {len(bodies):3d} {label:11s} {err} "
                      f"{h_coll(inner, bodies, body.faces):8.2%} {h_coll(outer, bodies, body.faces):8.2%} "
                      f"{lcoll:7.2%}", flush=True)


if __name__ == "__main__":
    main()
