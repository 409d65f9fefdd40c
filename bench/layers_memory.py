"""The memory the outer layer network takes on a long motion: its windows run at once, against OUTER_BATCH at a time.

The case an HTTP probe found (docs/layers.md): a layers request of 300 frames sent at 0.9 fps is resampled to
the network's 30 fps, 9,000 frames, and ONNX Runtime ran all of its windows in one call. Each variant runs in a
fresh process (`--child`): the served t-shirt + jacket networks loaded and the inputs made, the peak RSS
reset (/proc/self/clear_refs), then `OuterModel.pose_keys` once; printed: the peak RSS over the RSS before the
call (MB), the seconds, and the ratio of each to the batched default, in the same run. Linux only.

Run: PYTHONPATH=. .venv/bin/python -m bench.layers_memory [--frames 300] [--fps 0.9]   (about a minute)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _status_kb(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def child(frames: int, fps: float, batch: int) -> dict:
    """One variant in this process: -> {"peak_mb", "seconds", "windows", "keys_sha"}."""
    import hashlib

    from drape.assets.body import load_body
    from drape.assets.motion import load_clip
    from drape.runtime import layers

    inner, outer = layers.load_inner_model("tshirt"), layers.load_outer_model("tshirt", "jacket")
    assert inner is not None and outer is not None, "the t-shirt + jacket networks ship in the repository"
    layers.OUTER_BATCH = batch
    clip = load_clip("walk")
    reps = -(-frames // clip.num_frames)
    poses = np.tile(clip.poses.astype(np.float64), (reps, 1, 1))[:frames]
    trans = np.tile(clip.trans.astype(np.float64), (reps, 1))[:frames]
    keys_in = inner.pose_keys(poses)
    joints = load_body("neutral").joints
    Path("/proc/self/clear_refs").write_text("5")  # the peak RSS from here on
    before = _status_kb("VmRSS")
    start = time.perf_counter()
    keys = outer.pose_keys(poses, trans, fps, 0.008, keys_in, joints)
    seconds = time.perf_counter() - start
    at_model = int(round((frames - 1) * outer.fps / fps)) + 1
    return {"peak_mb": (_status_kb("VmHWM") - before) / 1024, "seconds": seconds,
            "windows": len(layers.window_starts(at_model, outer.window)[0]),
            "keys_sha": hashlib.sha256(np.ascontiguousarray(keys).tobytes()).hexdigest()[:12]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--fps", type=float, default=0.9)
    parser.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(child(args.frames, args.fps, args.child)))
        return
    from drape.runtime.layers import OUTER_BATCH

    rows = {}
    for name, batch in (("batched", OUTER_BATCH), ("all at once", 10**9)):
        out = subprocess.run([sys.executable, "-m", "bench.layers_memory", "--frames", str(args.frames), "--fps",
                              str(args.fps), "--child", str(batch)], capture_output=True, text=True, check=True)
        rows[name] = json.loads(out.stdout.strip().splitlines()[-1])
    base = rows["batched"]
    print(f"t-shirt + jacket outer network, {args.frames} frames at {args.fps:g} fps "
          f"({base['windows']} windows at 30 fps); same keys: {rows['all at once']['keys_sha'] == base['keys_sha']}")
    for name, r in rows.items():
        print(f"  {name:>12} ({OUTER_BATCH if name == 'batched' else r['windows']} per call): peak +{r['peak_mb']:.0f} MB "
              f"({r['peak_mb'] / base['peak_mb']:.2f}x), {r['seconds']:.2f} s ({r['seconds'] / base['seconds']:.2f}x)")


if __name__ == "__main__":
    main()
