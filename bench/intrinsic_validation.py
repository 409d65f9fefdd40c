"""Intrinsic garment models measured on ONE training config's validation split, with ONNX Runtime: the
training's checkpoint criterion (each parameter set's mean latent decoded along its frames' motion windows,
mean vertex error in mm; `drape.training.intrinsic.set_latent_error_of`) for several exported models, so
that a new run and the shipped model are compared on the same frames in the same run.

Rows: the whole validation split, then its parts: the validation parameter sets on the motions trained on,
the trained parameter sets on the validation motions (`val_motions`), and both held out. A model trained
with another config may have trained on some of these frames: the last column counts the validation frames
whose (motion, parameter set) the model's manifest lists among its training sequences (0 for a fair row, ? when the manifest does not list them).
Run: .venv/bin/python -m bench.intrinsic_validation --config drape/training/configs/intrinsic_skirt.json
     MODEL_DIR [MODEL_DIR ...]   (MODEL_DIR: an exported model folder, e.g. drape/assets/models/intrinsic/skirt)
"""

from __future__ import annotations

import argparse

import numpy as np

from drape.runtime.intrinsic import IntrinsicGarment
from drape.training.config_file import read_config
from drape.training.intrinsic import set_latent_error_of, training_datasets, validation_masks
from drape.training.intrinsic_data import Frames, load_frames


def parts(frames: Frames, val_params: int, val_motions: list[str]) -> dict[str, Frames]:
    """The training split's validation frames and their parts (a part left out when empty)."""
    held_set, held_motion = validation_masks(frames, val_params, val_motions)
    masks = {"validation": held_set | held_motion, "validation sets x trained motions": held_set & ~held_motion,
             "trained sets x validation motions": ~held_set & held_motion,
             "validation sets x validation motions": held_set & held_motion}
    return {k: frames.subset(m) for k, m in masks.items() if m.any()}


def trained_on(frames: Frames, manifest: dict) -> int | None:
    """How many of `frames` a model trained on: its manifest's `training.train_sequences`
    ({motion name: [parameter set, ...]}) matched against each frame's motion and parameter set;
    None when the manifest does not list them (models before 0.2.0)."""
    seen = manifest.get("training", {}).get("train_sequences")
    if seen is None:
        return None
    hit = np.zeros(len(frames), bool)
    for m, sets in seen.items():
        if m in frames.motion_names:
            hit |= (frames.motions == frames.motion_names.index(m)) & np.isin(frames.params, sets)
    return int(hit.sum())


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--config", required=True)
    p.add_argument("models", nargs="+")
    args = p.parse_args()
    config = read_config(args.config, "intrinsic")
    val_motions = list(config.get("val_motions", ()))
    garments = {m: IntrinsicGarment(m) for m in args.models}
    by_window: dict[int, dict[str, Frames]] = {}
    for g in garments.values():
        w = int(g.window)
        if w not in by_window:
            frames, _, _ = load_frames(training_datasets(config), w, ("train",))
            by_window[w] = parts(frames, config["val_params"], val_motions)
    names = list(next(iter(by_window.values())))
    print(f"config {args.config}: validation = last {config['val_params']} parameter sets + motions {val_motions}")
    print("| model | version | " + " | ".join(f"{n} (mm, frames)" for n in names) + " | validation frames trained on |")
    print("|---|---|" + "---|" * (len(names) + 1))
    for path, g in garments.items():
        cells = []
        for n in names:
            f = by_window[int(g.window)][n]
            err = set_latent_error_of(g._encode_local, g._decode_local, f)
            cells.append(f"{err:.2f} ({len(f)})")
        seen = trained_on(by_window[int(g.window)]["validation"], g.manifest)
        print(f"| {path} | {g.manifest.get('version', '?')} | " + " | ".join(cells) + f" | {'?' if seen is None else seen} |")


if __name__ == "__main__":
    main()
