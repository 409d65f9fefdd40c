"""Matched keyframes on ONE training config's validation split (never the test split): for evenly spaced
keyframes (first and last frame included) over each validation sequence, the mean vertex error (mm) of the
whole sequence for drape's latents alone, for drape with the keyframes matched at several fading time
constants (`drape.runtime.intrinsic.keyframe_residual`; "none": the residual interpolated linearly, no fading),
and for linear interpolation of the vertices in character space (`drape.training.intrinsic_eval.keyframe_errors`,
what the test table's keyframe ratio uses). This is how KEYFRAME_FADE_S was chosen.

Run: .venv/bin/python -m bench.intrinsic_keyframes --config drape/training/configs/intrinsic_skirt.json
     [--model drape/assets/models/intrinsic/skirt] [--fades 0.333,0.667,1.333,none]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from drape.runtime.intrinsic import INTRINSIC_DIR, IntrinsicGarment
from drape.training.config_file import read_config
from drape.training.intrinsic import training_datasets, validation_masks
from drape.training.intrinsic_data import load_frames
from drape.training.intrinsic_eval import keyframe_errors, load_sequence

COUNTS = (2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 30, 40)
NO_FADE_S = 1e9


def validation_items(config: dict, window: int) -> list[tuple[Path, dict]]:
    """(dataset folder, manifest item) of each sequence of the config's validation split, as training splits
    it (`drape.training.intrinsic.validation_masks` over every folder it trains on, `training_datasets`: the
    last `val_params` training parameter sets, every motion, and the `val_motions`, every parameter set)."""
    roots = [Path(d) for d in training_datasets(config)]
    frames, _, _ = load_frames(roots, window, ("train",))
    held_set, held_motion = validation_masks(frames, config["val_params"], list(config.get("val_motions", ())))
    val = held_set | held_motion
    pairs = {(int(p), frames.motion_names[m]) for p, m in zip(frames.params[val], frames.motions[val], strict=True)}
    return [(root, it) for root in roots for it in json.loads((root / "manifest.json").read_text())["items"]
            if it["split"] == "train" and (it["params"], it["motion"]) in pairs]


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--config", required=True)
    p.add_argument("--model", default=None, help="an exported model folder (default: the shipped template's)")
    p.add_argument("--fades", default="0.333,0.667,1.333,none", help="fading time constants, seconds, or none")
    args = p.parse_args()
    config = read_config(args.config, "intrinsic")
    garment = IntrinsicGarment(args.model or INTRINSIC_DIR / config["template"])
    fades = {f: (NO_FADE_S if f == "none" else float(f)) for f in args.fades.split(",")}
    items = validation_items(config, garment.window)
    rows = [keyframe_errors(garment, load_sequence(root, it), COUNTS,
                            {f"matched, fade {k}": f for k, f in fades.items()}) for root, it in items]
    methods = list(rows[0])
    print(f"model {garment.path} ({garment.version}), {len(items)} validation sequences of {args.config}; "
          "mean vertex error of the whole sequence (mm), mean over sequences")
    print("| keyframes | " + " | ".join(methods) + " |")
    print("|---|" + "---|" * len(methods))
    for k in (c for c in COUNTS if all(c in r["drape"] for r in rows)):
        print(f"| {k} | " + " | ".join(f"{np.mean([r[m][k] for r in rows]):.2f}" for m in methods) + " |")


if __name__ == "__main__":
    main()
