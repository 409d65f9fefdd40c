"""Two layers from DeePSD, and the refinement between layers (drape.geometry.layers).

Inputs: two layered outfits (tshirt + jacket, tanktop + longsleeve; 4,000 vertices together, generated as one
outfit and split, the served templates: drape.runtime.layers) on the neutral body, along the held-out clip dance_b and the
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
from drape.geometry.layers import LayerRefiner, LayerReport
from drape.geometry.mesh import unique_edges
from drape.geometry.refine import BodySurface, Refiner, RefineReport
from drape.runtime.engine import Engine
from drape.training.layers_eval import Rows, h_coll, l_coll

PAIRS = ("tshirt,jacket", "tanktop,longsleeve")
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


LabelledRows = dict[str, tuple[tuple[np.ndarray, np.ndarray], float]]


class LayerRows:
    """One served combination (`pair`: the catalog's templates; inner: vi, fi; outer: vo, fo), DeePSD's layers
    (`deepsd`: drape.training.layers_eval.Rows, the whole outfit and each layer rigged) and the refiners, made
    once; `rows` poses and refines them."""

    def __init__(self, engine: Engine, pair: str, thickness: float, body, surface: BodySurface):  # noqa: ANN001
        c = engine.layers.find(*pair.split(","))
        if c is None:
            raise ValueError(f"{pair}: not a served combination")
        self.deepsd = Rows(engine, c).deepsd
        (self.vi, self.fi), (self.vo, self.fo) = (c.inner.vertices, c.inner.faces), (c.outer.vertices, c.outer.faces)
        self.body, self.surface = body, surface
        self.layers = LayerRefiner(self.fi, len(self.vi), self.fo, len(self.vo), thickness, body.faces,
                                   len(body.vertices))
        self.body_i, self.body_o = Refiner(self.fi, len(self.vi)), Refiner(self.fo, len(self.vo))

    def rows(self, poses: np.ndarray, trans: np.ndarray, bodies: np.ndarray) -> LabelledRows:
        """poses (T, 24, 3), trans (T, 3), the posed bodies (T, M, 3) -> {label: ((inner (T, Ni, 3), outer
        (T, No, 3)), refinement seconds per frame)} for `one outfit`, `each alone`, `+ body`, `+ layers`."""
        one, (gi, go) = self.deepsd(poses, trans)
        rows: LabelledRows = {"one outfit": (one, 0.0), "each alone": ((gi, go), 0.0)}
        t = time.perf_counter()
        r = RefineReport()
        refined = tuple(np.stack([refiner.refine_frame(x, b, self.surface, r) for x, b in
                                  zip(frames, bodies, strict=True)]) for refiner, frames in
                        ((self.body_i, gi), (self.body_o, go)))
        rows["+ body"] = ((refined[0], refined[1]), (time.perf_counter() - t) / len(bodies))
        t = time.perf_counter()
        report = LayerReport()
        both = [self.layers.refine_frame(i, o, b, report) for i, o, b in zip(gi, go, bodies, strict=True)]
        rows["+ layers"] = ((np.stack([p[0] for p in both]), np.stack([p[1] for p in both])),
                            (time.perf_counter() - t) / len(bodies))
        return rows


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
        lr = LayerRows(engine, pair, args.thickness, body, surface)
        for name, poses, trans in clips(body, args.every):
            bodies = body.pose(poses, trans).astype(np.float64)
            rows = lr.rows(poses, trans, bodies)
            gi, go = rows["each alone"][0]
            for label, ((inner, outer), seconds) in rows.items():
                lcoll, sd, covered = l_coll(outer, inner, lr.fi)
                gap = float(np.median(sd[covered])) * 1e3
                longer = (new_long_edges(inner, gi, lr.vi, lr.fi) + new_long_edges(outer, go, lr.vo, lr.fo)
                          if label.startswith("+") else 0)
                print(f"{pair:19s} {name:11s} {len(bodies):4d} {label:12s} {h_coll(inner, bodies, body.faces):8.2%} "
                      f"{h_coll(outer, bodies, body.faces):8.2%} {lcoll:7.2%} {gap:7.1f} {longer:7d} "
                      f"{seconds * 1e3:8.1f}", flush=True)


if __name__ == "__main__":
    main()
