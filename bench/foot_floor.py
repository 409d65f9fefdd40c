"""Foot-floor error of the embedded clips on a body preset.

Per clip: the median over frames of the lower foot's height above the floor
(|lowest ankle/foot vertex y|, mm), for all clips and for the upright ones
(clips where the body lies, crawls, rolls or cartwheels keep feet off the floor
by design). Run: .venv/bin/python -m bench.foot_floor [--body neutral]
"""

from __future__ import annotations

import argparse

import numpy as np

from drape.assets.body import load_body
from drape.assets.deepmimic import foot_heights
from drape.assets.motion import list_clips, load_clip

ON_THE_GROUND = {"cartwheel", "crawl", "getup_facedown", "getup_faceup", "roll"}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--body", default="neutral")
    body = load_body(p.parse_args().body)
    rows = []
    for name in list_clips():
        err = float(np.median(np.abs(foot_heights(load_clip(name), body)))) * 1e3
        rows.append((name, err))
        print(f"{name:18s} {err:7.1f} mm{'  (body on the ground)' if name in ON_THE_GROUND else ''}")
    upright = [e for n, e in rows if n not in ON_THE_GROUND]
    print(f"median over {len(rows)} clips: {np.median([e for _, e in rows]):.1f} mm")
    print(f"median over {len(upright)} upright clips: {np.median(upright):.1f} mm")


if __name__ == "__main__":
    main()
