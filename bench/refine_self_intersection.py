"""Where refinement's largest edge stretches come from: a posed body that intersects itself.

The refine bench's inside test (and the issue's) is the closest-triangle sign. Where the posed
body intersects itself (the upper arm entering the torso at the armpit, the thighs pressed
together), a point can be inside one body part while its nearest surface belongs to the other
part and faces it: the sign calls it outside. The generalised winding number (`winding_number`)
counts it inside. This diagnostic refines the nearest-body-weights LBS baseline (the refine
bench's 6k long sleeve + trousers on dance_b) on a few frames and prints, for the input, drape's
refinement and the naive push:

- the share of garment vertices inside by each test;
- the largest edge stretch (elongation vs the input, mm) and, among the `top` most stretched
  edges of all frames, how many have an endpoint that the closest-triangle test calls outside
  but that lies inside the body by the winding number ("hidden": neither method can see it, so
  neither moves it, while its edge's other end is pushed out);
- the largest stretch over the edges with no hidden endpoint.

Winding numbers are brute force over the body's 27k triangles: the default run (2 frames x 3
point sets of 5,851 vertices) took 7 min 32 s on this machine. Run: .venv/bin/python -m bench.refine_self_intersection
"""

from __future__ import annotations

import argparse

import numpy as np

from bench.refine import baseline_input, posed_body
from drape.assets.outfits import generate_outfit
from drape.geometry.mesh import unique_edges
from drape.geometry.metrics import edge_lengths
from drape.geometry.queries import MeshDistance, winding_number
from drape.geometry.refine import BodySurface, Refiner, RefineReport, naive_push


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="0,40", help="dance_b frames (the refine bench's worst are 0 and 40)")
    parser.add_argument("--top", type=int, default=20, help="most stretched edges to classify")
    args = parser.parse_args()
    frames = np.array([int(f) for f in args.frames.split(",")])
    body, p, t, b = posed_body(frames)
    o = generate_outfit("longsleeve,trousers", vertices=6000, seed=77)
    edges = unique_edges(o.faces)
    g = baseline_input(o, body, p, t).astype(np.float64)
    surface = BodySurface(body.faces, len(body.vertices))
    refiner = Refiner(o.faces, len(o.vertices))
    outputs = {
        "input": g,
        "refine": np.stack([refiner.refine_frame(g[i], b[i], surface, RefineReport()) for i in range(len(g))]),
        "naive": np.stack([naive_push(g[i], b[i], surface) for i in range(len(g))]),
    }
    print(f"baseline LBS input, N = {len(o.vertices)}, dance_b frames {args.frames}")
    print(f"{'method':8s} {'inside % (closest tri)':>23s} {'inside % (winding)':>19s} {'spike mm':>9s} "
          f"{'hidden endpoint in top ' + str(args.top):>26s} {'spike mm, no hidden end':>24s}")
    distances = [MeshDistance(b[i], body.faces) for i in range(len(b))]  # one per posed body frame
    for name, r in outputs.items():
        sign = np.stack([d.signed_distance(r[i]) < 0 for i, d in enumerate(distances)])
        wind = np.stack([winding_number(r[i], b[i], body.faces) > 0.5 for i in range(len(r))])
        if name == "input":
            print(f"{name:8s} {100 * sign.mean():23.3f} {100 * wind.mean():19.3f}")
            continue
        stretch = edge_lengths(r, edges) - edge_lengths(g, edges)  # (T, E) metres
        top = np.argsort(stretch.ravel())[::-1][:args.top]
        frame, edge = np.divmod(top, stretch.shape[1])
        hidden = wind & ~sign  # (T, N) inside the body, outside by the closest-triangle sign
        ends = hidden[frame[:, None], edges[edge]].any(axis=1)
        clean = ~hidden[:, edges].any(axis=2)  # (T, E) edges with no hidden endpoint
        print(f"{name:8s} {100 * sign.mean():23.3f} {100 * wind.mean():19.3f} {1e3 * stretch.max():9.2f} "
              f"{int(ends.sum()):>21d} / {args.top} {1e3 * stretch[clean].max():24.2f}", flush=True)


if __name__ == "__main__":
    main()
