"""Keyframe latents pulled toward the training latents' mean, on ONE training config's validation split (never
the test split).

The held-out tables (docs/intrinsic.md) show decoding the mean training latent re-targets better than a
keyframe's own latent (skirt 52.0 against 68.8 mm, long skirt 119.9 against 146.8): the encoder's latent carries
the motion it was taken on. This bench measures, on validation sequences only, two ways to give a keyframe's
latent less of that:
- `shrink a`: z = mean + a (z_encoded - mean), a in [0, 1] (a = 1: the encoder's latent; a = 0: the mean);
- `shrink eb`: the same with a per latent dimension from the variances (empirical Bayes,
  drape.training.intrinsic_shrink: what `drape train intrinsic` now writes as the manifest's keyframe_shrink):
  between parameter sets (the manifest's latent_std) over between + within a set (the held-out sets' frames);
  with --calibrate-on, within from those sets only, and the scores on the validation sequences of the others;
- `fit l`: the latent that best decodes to the keyframe itself at its frame under a Gaussian prior (the
  training latents' mean and std), by Gauss-Newton from the encoder's latent (`fit_latent` below): it
  minimises mean squared vertex error / (1 cm)^2 + l * mean((z - mean) / std)^2.
Tasks, as the test table's (drape.training.intrinsic_eval), on the validation sequences:
- re-targeting: the middle frame of (p, m1) as the one keyframe, decoded along (p, m2), every ordered pair of
  validation sequences sharing a held-out parameter set; mean vertex error (mm);
- two keyframes: the first and last of the last 96 frames, latents interpolated, keyframes matched (the
  service's default) and unmatched; mean vertex error of the in-between frames (mm).

Validation is the config's: its last `val_params` training parameter sets on every motion and its `val_motions`
on every parameter set (the sequences the shipped model's manifest lists under training.val_sequences are of
these); only the config's main dataset is read (any of its extra datasets may be absent).

Run: .venv/bin/python -m bench.intrinsic_latent_prior --config drape/training/configs/intrinsic_skirt.json
     [--model DIR] [--shrink 0,0.25,0.5,0.75,1] [--fit 1,10 or "" for none] [--pairs 120]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from drape.geometry.character_space import character_space_numpy
from drape.geometry.metrics import mean_vertex_error_mm
from drape.runtime.intrinsic import INTRINSIC_DIR, IntrinsicGarment, MotionFrames
from drape.training.config_file import read_config
from drape.training.intrinsic_eval import WINDOW, load_sequence
from drape.training.intrinsic_shrink import set_latents, shrink_factors, validation_sequences

FIT_SCALE = 0.01  # m: the vertex error that weighs as much as one prior standard deviation at l = 1


def fit_latent(garment: IntrinsicGarment, shape: np.ndarray, frame: int, motion: MotionFrames, z0: np.ndarray,
               prior: float, iterations: int = 4, step: float = 1e-2) -> np.ndarray:
    """The latent (Z,) float32 whose decoding at `frame` of `motion` is nearest the keyframe `shape` (N, 3) m,
    world space, under the prior: minimises mean((decoded - shape)^2) / FIT_SCALE^2 + prior * mean(((z - mean) /
    std)^2) by Gauss-Newton from z0, the Jacobian by forward differences of `step` std per latent dimension (one
    ONNX Runtime call of Z + 1 decodings per iteration)."""
    local = character_space_numpy(np.asarray(shape, np.float64)[None], motion.root_position[[frame]],
                                  motion.root_rotation[[frame]])[0].reshape(-1)
    window = motion.windows(frame, frame + 1, garment.window)
    Z = garment.latent_size
    mean, std = garment.latent_mean, garment.latent_std
    n = local.size
    z = np.asarray(z0, np.float64).copy()
    windows = np.repeat(window, Z + 1, axis=0)
    h = step * std
    for _ in range(iterations):
        probe = np.repeat(z[None], Z + 1, axis=0)
        probe[np.arange(1, Z + 1), np.arange(Z)] += h
        out = garment._decode_local(probe.astype(np.float32), windows).reshape(Z + 1, -1).astype(np.float64)
        r = out[0] - local  # (n,)
        J = (out[1:] - out[0]).T / h  # (n, Z)
        # normal equations of sum(r + J d)^2 / (n s^2) + prior * sum(((z + d - mean) / std)^2) / Z
        a = J.T @ J / (n * FIT_SCALE**2) + prior * np.diag(1 / std**2) / Z
        b = -(J.T @ r) / (n * FIT_SCALE**2) - prior * (z - mean) / std**2 / Z
        z = z + np.linalg.solve(a, b)
    return z.astype(np.float32)


def _validation(config: dict, root: Path, trained: dict | None) -> tuple[list[dict], set[tuple[int, str]]]:
    """The config's validation sequences in its main dataset `root` (those simulated so far), and the (set, motion)
    of those of the held-out sets: the sets the model's training held out whole (`validation_sequences`: 36..39 for
    both templates) on every motion, and the `val_motions` on every parameter set."""
    held = {(it["params"], it["motion"]) for r, it in validation_sequences(config, trained) if r == root}
    m = json.loads((root / "manifest.json").read_text())
    return [it for it in m["items"] if it["split"] == "train"
            and ((it["params"], it["motion"]) in held or it["motion"] in config.get("val_motions", ()))], held


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--config", required=True)
    p.add_argument("--model", default=None)
    p.add_argument("--shrink", default="0,0.25,0.5,0.75,1")
    p.add_argument("--fit", default="1,10")
    p.add_argument("--pairs", type=int, default=120, help="at most this many re-targeting pairs (seeded sample)")
    p.add_argument("--calibrate-on", default="", help="held-out sets (comma list) the per-dimension factors are "
                   "measured on; the sequences of those sets are then left out of the scores (out-of-sample check)")
    args = p.parse_args()
    config = read_config(args.config, "intrinsic")
    garment = IntrinsicGarment(args.model or INTRINSIC_DIR / config["template"])
    root = Path(config["dataset"])
    items, held = _validation(config, root, garment.manifest.get("training"))
    seqs = {(it["params"], it["motion"]): load_sequence(root, it) for it in items}
    motions = {k: garment.motion_frames(s["poses"], s["trans"]) for k, s in seqs.items()}
    shrinks = [float(a) for a in args.shrink.split(",") if a]
    fits = [float(lam) for lam in args.fit.split(",") if lam]
    calib_sets = {int(x) for x in args.calibrate_on.split(",") if x}
    mean = garment.latent_mean
    garment.keyframe_shrink = np.ones(garment.latent_size)  # the encoder's own latents; each method shrinks them
    # empirical Bayes (drape.training.intrinsic_shrink, what `drape train intrinsic` writes as keyframe_shrink):
    # per latent dimension, between / (between + within), within over the frames of each held-out set's sequences
    per_set = set_latents(garment, ((p_, s) for (p_, m_), s in seqs.items()
                                    if (p_, m_) in held and (not calib_sets or p_ in calib_sets)))
    eb, within = shrink_factors(garment.latent_std**2, list(per_set.values()))
    print(f"empirical-Bayes shrink per dimension (sets {sorted(per_set)}): mean {eb.mean():.3f}, range "
          f"{eb.min():.3f}..{eb.max():.3f}; within / between variance {within.mean() / np.mean(garment.latent_std**2):.2f}")
    methods = [f"shrink {a:g}" for a in shrinks] + ["shrink eb"] + [f"fit {lam:g}" for lam in fits]

    def latents(key: tuple, frames: list[int]) -> dict[str, np.ndarray]:
        """Each method's latents (K, Z) of `frames` of sequence `key` as keyframes."""
        seq, motion = seqs[key], motions[key]
        z0 = garment.encode_at(seq["vertices"][frames], frames, motion).astype(np.float64)
        out = {f"shrink {a:g}": (mean + a * (z0 - mean)).astype(np.float32) for a in shrinks}
        out["shrink eb"] = (mean + eb * (z0 - mean)).astype(np.float32)
        for lam in fits:
            out[f"fit {lam:g}"] = np.stack([fit_latent(garment, seq["vertices"][f], f, motion, z, lam)
                                            for f, z in zip(frames, z0, strict=True)])
        return out

    scored = {k: v for k, v in seqs.items() if k[0] not in calib_sets}
    held_params = sorted({p for p, m in scored if sum(1 for q, _ in scored if q == p) > 1})
    pairs = [(a, b) for a in sorted(seqs) for b in sorted(seqs) if a[0] == b[0] and a != b and a[0] in held_params]
    rng = np.random.default_rng(0)
    if len(pairs) > args.pairs:
        pairs = [pairs[i] for i in sorted(rng.choice(len(pairs), args.pairs, replace=False))]
    t0 = time.perf_counter()
    rt: dict[str, list[float]] = {m: [] for m in methods}
    cache: dict[tuple, dict[str, np.ndarray]] = {}
    for a, b in pairs:
        k = len(seqs[a]["vertices"]) // 2
        if a not in cache:
            cache[a] = latents(a, [k])
        T2 = len(seqs[b]["vertices"])
        for m in methods:
            pred = garment.decode_motion(np.repeat(cache[a][m], T2, axis=0), motions[b])
            rt[m].append(mean_vertex_error_mm(pred, seqs[b]["vertices"]))
    kf: dict[str, list[float]] = {f"{m}{s}": [] for m in methods for s in ("", ", matched")}
    for key, seq in sorted(scored.items()):
        T = len(seq["vertices"])
        a, b = T - WINDOW, T - 1
        between = slice(a + 1, b)
        zs = latents(key, [a, b])
        for m in methods:
            z = garment.interpolate(list(zip([a, b], zs[m], strict=True)), T)
            residual = garment.keyframe_residual(seq["vertices"][[a, b]], [a, b], [], z, motions[key], seq["fps"])
            kf[m].append(mean_vertex_error_mm(garment.decode_motion(z, motions[key])[between],
                                              seq["vertices"][between]))
            kf[f"{m}, matched"].append(mean_vertex_error_mm(
                garment.decode_motion(z, motions[key], residual=residual)[between], seq["vertices"][between]))
    print(f"model {garment.path} ({garment.version}); {len(scored)} validation sequences of {root} scored "
          f"(sets {sorted({p for p, _ in scored})[:3]}..., motions {sorted({m for _, m in scored})}); "
          f"{len(pairs)} re-targeting pairs over sets {held_params}; {time.perf_counter() - t0:.0f} s")
    print("| latent | re-targeting (mm) | two keyframes (mm) | two keyframes, matched (mm) |")
    print("|---|---|---|---|")
    for m in methods:
        print(f"| {m} | {np.mean(rt[m]):.2f} | {np.mean(kf[m]):.2f} | {np.mean(kf[m + ', matched']):.2f} |")


if __name__ == "__main__":
    main()
