"""Refinement of a stream split over worker processes, timed against one process in the same run.

Input: the long sleeve + trousers outfit at about 6k vertices on the held-out clip dance_b (every
5th frame, 31 frames: one 32-frame chunk of the service), posed by the nearest-body-weights LBS
baseline and by the shipped DeePSD. The path timed is the service's: `Engine.refine_chunks` (the
body posed for the chunk, then the frames refined, in process with `refine_workers=1`, split over
2 worker processes with 2). Each pass refines the stream with both engines, alternating which goes
first; the workers are started before the first pass. Printed per input and refine setting (the
defaults, with the stretch relief pass; no relief = `relief_iterations=0`): ms per frame of the stream, median and range over the
passes, and the ratio one process / two workers per pass. Both give the same output (checked).

Run: .venv/bin/python -m bench.refine_parallel (about 2 minutes on the 2-core machine)
"""

from __future__ import annotations

import time

import numpy as np

from bench.refine import penetrating_inputs, posed_body
from bench.refine_relief_cost import spread
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.runtime.deepsd import DeePSDModel
from drape.runtime.engine import Engine, RefineSettings

PASSES = 7


def main() -> None:
    clip = load_clip("dance_b")
    frames = np.arange(0, clip.num_frames, 5)
    body, p, t, _ = posed_body(frames)
    o = generate_outfit("longsleeve,trousers", vertices=6000, seed=77)
    engines = {"1 process": Engine(refine_workers=1), "2 workers": Engine(refine_workers=2)}
    engines["2 workers"].refine_pool.start()
    print(f"N = {len(o.vertices)}, {len(frames)} frames, {PASSES} passes")
    print(f"{'input':8s} {'refine':8s} {'1 process ms/frame':>22s} {'2 workers ms/frame':>22s} {'ratio':>20s}")
    try:
        for source, g in penetrating_inputs(DeePSDModel(), o, body, p, t).items():
            g = g.astype(np.float32)
            for setting, options in (("defaults", RefineSettings()), ("norelief", RefineSettings(relief_iterations=0))):
                ms = {name: np.zeros(PASSES) for name in engines}
                outputs = {}
                for k in range(PASSES):
                    for name in (list(engines) if k % 2 == 0 else list(reversed(engines))):
                        t0 = time.perf_counter()
                        outputs[name] = np.concatenate(list(engines[name].refine_chunks(g, o.faces, "neutral", p, t,
                                                                                         options)))
                        ms[name][k] = (time.perf_counter() - t0) / len(g) * 1e3
                assert np.array_equal(outputs["1 process"], outputs["2 workers"])
                ratio = ms["1 process"] / ms["2 workers"]
                print(f"{source:8s} {setting:8s} {spread(ms['1 process']):>22s} {spread(ms['2 workers']):>22s} "
                      f"{spread(ratio):>20s}", flush=True)
    finally:
        for engine in engines.values():
            engine.close()


if __name__ == "__main__":
    main()
