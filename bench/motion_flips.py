"""Rotation flips in the real CMU clips, before and after the importer's repair (drape.assets.motion_flips).

For each BVH in ../shared/data/mocap (and the external fairmotion 01_01), imported at its own frame rate on the
neutral body with and without the repair: the largest frame-to-frame turn of any joint (rad), how many frames
turn a joint by over 1 rad, and the spans the repair replaced.
Run: .venv/bin/python -m bench.motion_flips [--dir ../shared/data/mocap]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import import_motion
from drape.assets.motion_flips import FLIP_RAD, _angles
from drape.geometry.rotations import axis_angle_to_quaternion


def largest_turns(poses: np.ndarray) -> np.ndarray:
    """poses (T, J, 3) -> (T - 1,) the largest turn of any joint from each frame to the next, rad."""
    q = axis_angle_to_quaternion(np.asarray(poses, dtype=np.float64))
    return _angles(q[:-1], q[1:]).max(axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default="../shared/data/mocap")
    parser.add_argument("--external", default="../shared/data/external/fairmotion_01_01.bvh")
    args = parser.parse_args()
    body = load_body("neutral")
    files = sorted(Path(args.dir).glob("*.bvh")) + [p for p in [Path(args.external)] if p.exists()]
    print("clip | fps | frames | largest turn rad: raw / repaired | frames over 1 rad: raw / repaired | spans repaired")
    n_with = 0
    for f in files:
        data = f.read_bytes()
        raw = import_motion(data, body, flips=False, floor=False, name=f.stem).motion
        rep = import_motion(data, body, floor=False, name=f.stem)
        a, b = largest_turns(raw.poses), largest_turns(rep.motion.poses)
        n_with += bool(rep.flips)
        print(f"{f.stem} | {raw.fps:g} | {raw.num_frames} | {a.max():.2f} / {b.max():.2f} | "
              f"{int((a > FLIP_RAD).sum())} / {int((b > FLIP_RAD).sum())} | "
              f"{'; '.join(x.describe() for x in rep.flips) or '-'}", flush=True)
    print(f"{n_with} of {len(files)} clips repaired")


if __name__ == "__main__":
    main()
