"""What the stretch relief pass (on by default) costs, timed against refinement without it in the same
run, interleaved.

Input: the long sleeve + trousers outfit at about 6k vertices on the held-out clip dance_b (every
5th frame, 31 frames), posed by the nearest-body-weights LBS baseline and by the shipped DeePSD.
Each pass over the frames refines every frame twice, with the defaults (10 relief rounds) and with
`relief_iterations=0`, alternating which goes first, so both see the same machine load. Printed
per input: the mean ms per frame of each pass (median and range over the passes), and the ratio
defaults / no relief per pass (median and range).

Run: .venv/bin/python -m bench.refine_relief_cost (about 1 minute on the 2-core machine)
"""

from __future__ import annotations

import time

import numpy as np

from bench.refine import penetrating_inputs, posed_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.refine import BodySurface, Refiner, RefineReport
from drape.runtime.deepsd import DeePSDModel

PASSES = 15


def spread(x: np.ndarray) -> str:
    """Per-pass figures (PASSES,) -> 'median (min-max)'."""
    return f"{np.median(x):.2f} ({x.min():.2f}-{x.max():.2f})"


def main() -> None:
    body, p, t, b = posed_body(np.arange(0, load_clip("dance_b").num_frames, 5))
    surface = BodySurface(body.faces, len(body.vertices))
    o = generate_outfit("longsleeve,trousers", vertices=6000, seed=77)
    refiners = {"no relief": Refiner(o.faces, len(o.vertices), relief_iterations=0),
                "defaults": Refiner(o.faces, len(o.vertices))}
    print(f"N = {len(o.vertices)}, {len(b)} frames, {PASSES} passes")
    print(f"{'input':8s} {'no relief ms/frame':>24s} {'defaults ms/frame':>24s} {'defaults / no relief':>24s}")
    for source, g in penetrating_inputs(DeePSDModel(), o, body, p, t).items():
        g = g.astype(np.float64)
        for r in refiners.values():  # warm up: first-call costs out of the timings
            r.refine_frame(g[0], b[0], surface, RefineReport())
        seconds = {name: np.zeros(PASSES) for name in refiners}
        for k in range(PASSES):
            order = list(refiners) if k % 2 == 0 else list(reversed(refiners))
            for i in range(len(g)):
                for name in order:
                    t0 = time.perf_counter()
                    refiners[name].refine_frame(g[i], b[i], surface, RefineReport())
                    seconds[name][k] += time.perf_counter() - t0
        ms = {name: s / len(g) * 1e3 for name, s in seconds.items()}
        ratio = ms["defaults"] / ms["no relief"]
        print(f"{source:8s} {spread(ms['no relief']):>24s} {spread(ms['defaults']):>24s} {spread(ratio):>24s}",
              flush=True)


if __name__ == "__main__":
    main()
