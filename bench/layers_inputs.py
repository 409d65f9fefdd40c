"""How the served layer networks answer two inputs a request sets: the motion's frame rate and the thickness.

- fps: each embedded clip (walk, dance_b) sent at 30 fps and, resampled by slerp, at 60 fps; the outer layer at
  the 60 fps motion's even frames against the 30 fps answer (max / mean mm; 0 since the outer network reads any
  motion at the 30 fps it was trained at, docs/layers.md).
- thickness: the same clip at both ends of the combination's thickness range; how far the outer layer moves
  (max / mean mm), the median distance of the outer layer to the inner (over the vertex-frames over it, every 5th
  frame, drape.sim.quality.outer_inner_distance) and the share of those closer to it than H_in, at each end
  (the simulation keeps its 10th percentile at about H_in + 0.5 mm).

Both through Engine.layer_chunks (what POST /v1/layers/animate answers without refine).
Run: PYTHONPATH=. .venv/bin/python -m bench.layers_inputs   (a few minutes on 2 cores)
"""

from __future__ import annotations

import numpy as np

from drape.assets.motion import Motion, load_clip, resample
from drape.runtime.engine import Engine
from drape.sim.quality import outer_inner_distance


def _outer(engine: Engine, combination, thickness: float, poses: np.ndarray, trans: np.ndarray,  # noqa: ANN001
           fps: float) -> tuple[np.ndarray, np.ndarray]:
    parts = list(engine.layer_chunks(combination, thickness, poses, trans, fps=fps))
    return np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts])


def main() -> None:
    engine = Engine(refine_workers=1)
    try:
        for pair in (("tshirt", "jacket"), ("tanktop", "longsleeve")):
            c = engine.layers.find(*pair)
            lo, hi = c.thickness
            for name in ("walk", "dance_b", "punch"):
                clip = load_clip(name)
                p, t = clip.poses.astype(np.float64), clip.trans.astype(np.float64)
                if name != "punch":
                    fast = resample(Motion(p, t, 30.0), 60.0)
                    a = _outer(engine, c, 0.008, p, t, 30.0)[1]
                    b = _outer(engine, c, 0.008, fast.poses.astype(np.float64), fast.trans.astype(np.float64), 60.0)[1]
                    d = np.linalg.norm(b[::2] - a, axis=-1) * 1e3
                    print(f"{'+'.join(pair)} {name}: 60 fps against 30 fps, max {d.max():.3f} mm, mean {d.mean():.4f} mm")
                layers = {h: _outer(engine, c, h, p, t, clip.fps) for h in (lo, hi)}
                move = np.linalg.norm(layers[hi][1] - layers[lo][1], axis=-1) * 1e3
                gaps = {}
                for h, (inner, outer) in layers.items():
                    sd, covered = outer_inner_distance(outer[::5], inner[::5], c.inner.faces)
                    gaps[h] = sd[covered]
                print(f"{'+'.join(pair)} {name}: H_in {lo} -> {hi} m moves the outer max {move.max():.1f} mm, mean "
                      f"{move.mean():.2f} mm; gap median {1e3 * np.median(gaps[lo]):.1f} / {1e3 * np.median(gaps[hi]):.1f}"
                      f" mm; closer than H_in {100 * np.mean(gaps[lo] < lo):.2f}% / {100 * np.mean(gaps[hi] < hi):.2f}%")
    finally:
        engine.close()


if __name__ == "__main__":
    main()
