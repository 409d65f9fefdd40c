"""What a rig costs as the garment grows: seconds and peak memory of `Engine.rig` (the served rig: DeePSD's
network, the 4-influence refit and the collision fit) at several vertex counts, each in a fresh process.

Per size: a generated t-shirt of about that many vertices (seed 3), the engine loaded and its fit frames made
first; then the peak RSS reset (/proc/self/clear_refs) and one rig timed, in two stages: the network's dense rig
(`DeePSDModel.rig`) and the served rig on it (`served_rig`). Printed: each stage's seconds, the peak RSS over the
RSS before the rig (after the network, and over the whole rig), what the process keeps after it, per 1,000
vertices too, and each size's ratio to the smallest's (same run), so the scaling is read on a noisy machine.
Linux only.

Run: PYTHONPATH=. .venv/bin/python -m bench.rig_scale [--sizes 6000,12000,24000,48000]   (about 2 min)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path


def _mb(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    raise KeyError(key)


def child(vertices: int) -> dict:
    from drape.assets.body import load_body
    from drape.assets.outfits import generate_outfit
    from drape.runtime.collision_fit import served_rig
    from drape.runtime.engine import Engine

    engine = Engine(refine_workers=1)
    try:
        outfit = generate_outfit("tshirt", vertices=vertices, seed=3)
        body = load_body("neutral")
        engine.served_frames()
        out = {"vertices": len(outfit.vertices)}
        Path("/proc/self/clear_refs").write_text("5")
        before, start = _mb("VmRSS"), time.perf_counter()
        dense = engine.model.rig(outfit.vertices, outfit.faces, body)
        out["network_s"], out["network_mb"] = time.perf_counter() - start, _mb("VmHWM") - before
        start = time.perf_counter()
        served_rig(outfit.vertices, dense, body, 4, engine.fit_frames(), engine.collision_frames(), faces=outfit.faces)
        out["served_s"], out["peak_mb"] = time.perf_counter() - start, _mb("VmHWM") - before
        out["after_mb"] = _mb("VmRSS") - before
        return out
    finally:
        engine.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="6000,12000,24000,48000")
    parser.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return
    rows = []
    for size in (int(s) for s in args.sizes.split(",")):
        out = subprocess.run([sys.executable, "-m", "bench.rig_scale", "--child", str(size)], capture_output=True,
                             text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    base = rows[0]
    print("vertices | network s, +MB peak | served rig s | rig s, +MB peak, +MB kept after | per 1k vertices: s, "
          "MB peak | x smallest (s, MB)")
    base_s = base["network_s"] + base["served_s"]
    for r in rows:
        total_s = r["network_s"] + r["served_s"]
        print(f"{r['vertices']:>8} | {r['network_s']:.1f}, +{r['network_mb']:.0f} | {r['served_s']:.1f} | "
              f"{total_s:.1f}, +{r['peak_mb']:.0f}, +{r['after_mb']:.0f} | {1e3 * total_s / r['vertices']:.2f}, "
              f"{1e3 * r['peak_mb'] / r['vertices']:.0f} | {total_s / base_s:.1f}x, {r['peak_mb'] / base['peak_mb']:.1f}x")


if __name__ == "__main__":
    main()
