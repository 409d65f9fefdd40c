"""What a rig costs as the garment grows: seconds and peak memory of `Engine.rig` (the served rig: DeePSD's
network, the 4-influence refit and the collision fit) at several vertex counts, each in a fresh process.

Per size: a generated t-shirt of about that many vertices (seed 3), the engine loaded and its fit frames made
first; then the peak RSS reset (/proc/self/clear_refs) and one rig timed, in two stages: the network's dense rig
(`DeePSDModel.rig`) and the served rig on it (`served_rig`). Printed: seconds and peak MB over the RSS before
each stage (ONNX Runtime keeps its arena after the network's run: the rig's peak is the sum), per 1,000 vertices
too, and each size's ratio to the smallest's (same run), so the scaling is read
on a noisy machine. Linux only.

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
        Path("/proc/self/clear_refs").write_text("5")
        before, start = _mb("VmRSS"), time.perf_counter()
        served_rig(outfit.vertices, dense, body, 4, engine.fit_frames(), engine.collision_frames(), faces=outfit.faces)
        out["served_s"], out["served_mb"] = time.perf_counter() - start, _mb("VmHWM") - before
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
    # ONNX Runtime keeps its arena after the network's run, so the served stage's peak sits on top of it: the
    # rig's peak over the RSS before it is the sum
    print("vertices | network s / +MB | served rig s / +MB | rig s, +MB; per 1k vertices | x smallest (s, MB)")
    for r in rows:
        total_s = r["network_s"] + r["served_s"]
        peak = r["network_mb"] + r["served_mb"]
        base_s = base["network_s"] + base["served_s"]
        base_peak = base["network_mb"] + base["served_mb"]
        print(f"{r['vertices']:>8} | {r['network_s']:.1f} / +{r['network_mb']:.0f} | {r['served_s']:.1f} / "
              f"+{r['served_mb']:.0f} | {total_s:.1f} s, +{peak:.0f} MB; {1e3 * total_s / r['vertices']:.2f} s, "
              f"{1e3 * peak / r['vertices']:.0f} MB | {total_s / base_s:.1f}x, {peak / base_peak:.1f}x")


if __name__ == "__main__":
    main()
