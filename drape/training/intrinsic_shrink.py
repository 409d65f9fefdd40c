"""Keyframe latents pulled toward the training mean (empirical Bayes), calibrated on a config's validation split.

The encoder's latent of one keyframe is the garment's intrinsic parameters plus what the frame's motion leaves
in it: over the frames of one parameter set its latents scatter (`within`, per latent dimension) around the set's
mean, and the sets' means scatter around the training mean (`between`: the manifest's `latent_std` squared,
`drape.training.intrinsic.latent_statistics`). Given one frame's latent z, the best guess of its set's mean
(normal priors) is mean + s (z - mean) with s = between / (between + within) per dimension: the manifest's
`keyframe_shrink`, which `drape.runtime.intrinsic.IntrinsicGarment.encode_at` applies to every keyframe latent.

`within` is measured with the exported model (ONNX Runtime) on the validation parameter sets its training held out
whole (`validation_sequences`), each on every training motion simulated: the sets trained on none of their frames,
so the scatter is what an unseen garment's keyframes show. Chosen on that split against the encoder's
latent alone and fixed shrink factors (bench/intrinsic_latent_prior.py; docs/intrinsic.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from drape.training.intrinsic import training_datasets


def shrink_factors(between_var: np.ndarray, per_set_latents: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """between_var (Z,): variance of the parameter sets' mean latents; per_set_latents: one (T_i, Z) array of
    latents per parameter set (its frames, pooled over its motions) -> (shrink (Z,) in [0, 1], within (Z,): the
    mean over sets of each set's variance over its frames)."""
    if not per_set_latents:
        raise ValueError("no parameter set to measure the within-set variance on")
    within = np.mean([np.asarray(z, np.float64).var(axis=0) for z in per_set_latents], axis=0)
    between = np.asarray(between_var, np.float64)
    return between / np.maximum(between + within, 1e-30), within


def set_latents(garment, sequences) -> dict[int, np.ndarray]:  # noqa: ANN001
    """The encoder's own latents (`IntrinsicGarment.encode_frames`) of every frame of `sequences`, an iterable of
    (parameter set, sequence {"vertices", "poses", "trans"}), pooled per parameter set -> {set: (frames, Z)}."""
    per_set: dict[int, list[np.ndarray]] = {}
    for p, s in sequences:
        per_set.setdefault(int(p), []).append(garment.encode_frames(s["vertices"], s["poses"], s["trans"]))
    return {p: np.concatenate(z) for p, z in per_set.items()}


def validation_sequences(config: dict, trained: dict | None = None) -> list[tuple[Path, dict]]:
    """(dataset folder, manifest item) of every simulated training-split sequence of the validation parameter sets, in
    each of the config's dataset folders that exists (a folder not simulated on this machine is skipped; the manifest
    records which were read). trained: the model manifest's `training` record; its sets are those of its
    `val_sequences` that no `train_sequences` holds (the sets training held out whole). Without one, training's
    rule: the last `val_params` training parameter sets present (`drape.training.intrinsic.validation_masks`)."""
    items = []
    for root in map(Path, training_datasets(config)):
        if (root / "manifest.json").exists():
            m = json.loads((root / "manifest.json").read_text())
            items += [(root, it) for it in m["items"] if it["split"] == "train"]
    if trained and "train_sequences" in trained and "val_sequences" in trained:
        seen = {int(p) for sets in trained["train_sequences"].values() for p in sets}
        held = {int(p) for sets in trained["val_sequences"].values() for p in sets} - seen
    else:
        held = set(sorted({int(it["params"]) for _, it in items})[-config["val_params"]:])
    return [(root, it) for root, it in items if it["params"] in held]


def calibrate(model_dir: str | Path, config: dict, log=print) -> dict:  # noqa: ANN001
    """Measure `keyframe_shrink` for the exported model in `model_dir` on the config's validation sets and write it
    (with where it came from) into the model's manifest.json, whose version becomes the export's VERSION (0.3.1 is
    the first with the shrink: the same networks as 0.3.0) -> the fields written."""
    from drape.export.intrinsic import VERSION
    from drape.runtime.intrinsic import IntrinsicGarment
    from drape.training.intrinsic_eval import load_sequence

    garment = IntrinsicGarment(model_dir)
    trained = garment.manifest.get("training") or {}
    was = trained.get("config") or {}
    for key in ("dataset", "val_params"):
        if key in was and was[key] != config.get(key):
            raise ValueError(f"{model_dir} was trained with {key} {was[key]!r}, the config given has "
                             f"{config.get(key)!r}: calibrate with the config it was trained with")
    seqs = validation_sequences(config, trained)
    per_set = set_latents(garment, ((it["params"], load_sequence(root, it)) for root, it in seqs))
    between = garment.latent_std**2
    shrink, within = shrink_factors(between, list(per_set.values()))
    fields = {"version": VERSION, "keyframe_shrink": [round(float(x), 6) for x in shrink],
              "keyframe_shrink_source": {
                  "datasets": sorted({str(root) for root, _ in seqs}), "sequences": len(seqs),
                  "parameter_sets": sorted(per_set), "within_over_between": float(within.mean() / between.mean()),
                  "mean_shrink": float(shrink.mean())}}
    path = Path(model_dir) / "manifest.json"
    manifest = json.loads(path.read_text())
    path.write_text(json.dumps(manifest | fields, indent=2) + "\n")
    log(f"{path}: keyframe_shrink from {len(seqs)} validation sequences of sets {sorted(per_set)}: mean "
        f"{shrink.mean():.3f} ({shrink.min():.3f}..{shrink.max():.3f}), within / between {within.mean() / between.mean():.2f}")
    return fields
