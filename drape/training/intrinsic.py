"""`drape train intrinsic --template NAME`: the intrinsic garment space of one template (Wang et al. 2019).

One config (drape/training/configs/intrinsic_<template>.json), two phases, one command:

1. shape: the shape autoencoder N_E/N_D on every training frame, L2 + Laplacian losses;
2. invariant: N_E frozen; M_E, F_E, F_D on batches of `sets_per_batch` parameter sets x
   `frames_per_set` frames (frames of one set come from all its motions). Loss per batch:
   mean within-set variance of z over the variance of the set means (motion invariance, scale-free)
   + lambda * ||S - F_D(F_E(S, c), c)||^2 (descriptor reconstruction) + set_lambda * ||S - F_D(z_set, c)||^2
   with z_set the mean z of the frame's set in the batch (reconstruction from the set's latent, which is
   how a keyframe is used; set_lambda 0, the default, is the paper's loss).

Validation: the last `val_params` training parameter sets and every frame of the `val_motions` (optional,
motion names of the training split) are held out of training (the dataset's own
held-out parameter sets and motions are never read here: they are the test table's). After each
phase's checkpoints the validation error is measured: phase 1, mean vertex error (mm) of the shape
autoencoder; phase 2, mean vertex error (mm) of decoding each validation set's mean latent along
its frames' motion windows (what one keyframe gives); the best checkpoint of each phase is kept.

Data: the config's `dataset` and, optionally, `extra_datasets` (folders simulated with the same template
and parameter sampler, e.g. more training motions; `training_datasets`), their training splits read together.

Checkpoints (git-ignored) go to `checkpoints/intrinsic/<template>/`, each written whole or not at all; a rerun
resumes where the last one left off, with the batches the uninterrupted run would have drawn, and refuses
checkpoints of a run of another config or on other training or validation sequences (validated_steps'
check_same_config / check_same_data, as the other trainers). Seeded.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from drape.models.intrinsic import IntrinsicConfig, IntrinsicSpace, uniform_laplacian_loss
from drape.training.config_file import named_config, read_config
from drape.training.intrinsic_data import Frames, load_frames
from drape.training.validated_steps import check_same_config, check_same_data, save_whole


def load_config(template: str | None = None, path: str | Path | None = None) -> dict:
    return read_config(Path(path), "intrinsic") if path else named_config("intrinsic", str(template), "--template")


def training_datasets(config: dict) -> list[str]:
    """The dataset folders a config trains on: `dataset` (its template mesh, its test split: the evaluation's),
    then any `extra_datasets` (more training sequences of the same template and parameter sampler)."""
    return [config["dataset"], *config.get("extra_datasets", [])]


def validation_masks(frames: Frames, val_params: int, val_motions: tuple[str, ...] | list[str] = ()
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(held_set, held_motion), (F,) bool each: the frames of the last `val_params` parameter sets present,
    and the frames of the motions named in `val_motions` (motion names of the training split)."""
    sets = np.unique(frames.params)
    if not 0 < val_params < len(sets):
        raise ValueError(f"val_params must be in [1, {len(sets) - 1}] for {len(sets)} parameter sets")
    missing = [m for m in val_motions if m not in frames.motion_names]
    if missing:
        raise ValueError(f"val_motions {missing} are not among the training motions {frames.motion_names}")
    if len(set(val_motions)) >= len(frames.motion_names):
        raise ValueError("val_motions would leave no training motion")
    return (np.isin(frames.params, sets[-val_params:]),
            np.isin(frames.motions, [frames.motion_names.index(m) for m in val_motions]))


def split_validation(frames: Frames, val_params: int, val_motions: tuple[str, ...] | list[str] = ()
                     ) -> tuple[Frames, Frames]:
    """(training, validation) frames: the frames of `validation_masks` are validation; training has neither
    (so validation also measures motions never trained on, which is what the test table asks of the model)."""
    held_set, held_motion = validation_masks(frames, val_params, val_motions)
    val = held_set | held_motion
    return frames.subset(~val), frames.subset(val)


def edges_of(faces: np.ndarray) -> torch.Tensor:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    return torch.as_tensor(e, dtype=torch.int64)


def build_model(config: dict, frames: Frames) -> IntrinsicSpace:
    cfg = IntrinsicConfig(num_vertices=frames.vertices.shape[1], **config["model"])
    return IntrinsicSpace(cfg, torch.as_tensor(frames.vertices.mean(axis=0)))


@torch.no_grad()
def shape_error_mm(model: IntrinsicSpace, frames: Frames, batch: int = 512) -> float:
    err = []
    for s in range(0, len(frames), batch):
        v = torch.as_tensor(frames.vertices[s:s + batch])
        err.append((model.shape.decode(model.shape.encode(v)) - v).norm(dim=-1).mean(dim=1))
    return float(torch.cat(err).mean() * 1e3)


@torch.no_grad()
def set_latent_error_mm(model: IntrinsicSpace, frames: Frames) -> float:
    """Decode each parameter set's mean latent along its frames' windows: mean vertex error, mm."""
    def encode(v: np.ndarray, w: np.ndarray) -> np.ndarray:
        return model.encode(torch.as_tensor(v), torch.as_tensor(w)).numpy()

    def decode(z: np.ndarray, w: np.ndarray) -> np.ndarray:
        return model.decode(torch.as_tensor(z), torch.as_tensor(w)).numpy()

    return set_latent_error_of(encode, decode, frames)


def set_latent_error_of(encode, decode, frames: Frames) -> float:  # noqa: ANN001
    """`set_latent_error_mm` of any implementation: encode(vertices (F, N, 3), windows (F, W + 1, 24, 3))
    -> latents (F, Z); decode(latents, windows) -> vertices (F, N, 3); character space, float32 m.
    Mean over the parameter sets of the mean vertex error, mm."""
    errs = []
    for p in np.unique(frames.params):
        f = frames.subset(frames.params == p)
        z = encode(f.vertices, f.windows).mean(axis=0, keepdims=True).repeat(len(f), axis=0)
        errs.append(np.linalg.norm(decode(z.astype(np.float32), f.windows) - f.vertices, axis=-1).mean())
    return float(np.mean(errs) * 1e3)


def invariant_loss(model: IntrinsicSpace, v: torch.Tensor, w: torch.Tensor, sets: int, lam: float,
                   set_lam: float = 0.0) -> tuple[torch.Tensor, dict]:
    """v (sets * n, N, 3), w (sets * n, W + 1, 24, 3), grouped by set -> loss and its parts.

    ratio (within-set over between-set variance of z) + lam * descriptor reconstruction from each frame's own
    z (the paper's loss) + set_lam * reconstruction from the mean z of the frame's set (`set_recon`: what a
    keyframe gives at the other frames; 0 leaves the paper's loss)."""
    with torch.no_grad():
        s = model.shape.encode(v)
    c = model.motion(w)
    z = model.f_encoder(s, c)
    zs = z.reshape(sets, -1, z.shape[1])
    within = zs.var(dim=1).mean()
    between = zs.mean(dim=1).var(dim=0).mean()
    recon = ((model.f_decoder(z, c) - s) ** 2).mean()
    ratio = within / (between + 1e-6)
    loss = ratio + lam * recon
    parts = {"ratio": ratio.item(), "recon": recon.item()}
    if set_lam > 0:
        z_set = zs.mean(dim=1, keepdim=True).expand_as(zs).reshape(z.shape)
        set_recon = ((model.f_decoder(z_set, c) - s) ** 2).mean()
        loss = loss + set_lam * set_recon
        parts["set_recon"] = set_recon.item()
    return loss, parts


def _sequences(frames: Frames) -> dict[str, list[int]]:
    """The sequences a frame set holds: motion name -> its parameter-set indices (what a part-way dataset
    trained on, for the manifest)."""
    return {name: sorted({int(p) for p in np.unique(frames.params[frames.motions == i])})
            for i, name in enumerate(frames.motion_names) if np.any(frames.motions == i)}


def _latest(ckpt_dir: Path, phase: str) -> Path | None:
    found = sorted(ckpt_dir.glob(f"{phase}_*.pt"), key=lambda p: int(p.stem.split("_")[-1]))
    return found[-1] if found else None


def _split_sequences(run: dict) -> dict[str, list[str]]:
    """A run record ({"train_sequences"|"val_sequences": {motion: [parameter sets]}}) as check_same_data's
    {split: ["motion/set", ...]}."""
    return {split: [f"{motion}/{p}" for motion, sets in run[key].items() for p in sets]
            for split, key in (("train", "train_sequences"), ("validation", "val_sequences"))}


def _resume(path: Path, run: dict, config: dict) -> dict:
    """A checkpoint's state, when it was written by a run of the same config (check_same_config) on the same
    training and validation sequences (check_same_data: the dataset grew, or the config's datasets or validation
    split changed); checkpoints from before either check carry no record of it and are taken."""
    state = torch.load(path, weights_only=False)
    if "config" in state:
        check_same_config(json.loads(state["config"]), config, path)
    if "run" in state:
        check_same_data(_split_sequences(state["run"]), _split_sequences(run), path)
    return state


def train(config: dict, ckpt_dir: str | Path | None = None, log=print) -> tuple[IntrinsicSpace, dict]:
    """Run (or resume) both phases; returns the model with each phase's best (validation) weights and a
    summary (validation figures, steps, seconds, the config)."""
    from tqdm import tqdm

    ckpt = Path(ckpt_dir or f"checkpoints/intrinsic/{config['template']}")
    torch.manual_seed(config["seed"])
    rng = np.random.default_rng(config["seed"])
    window = config["model"]["window"]
    frames, faces, manifest = load_frames(training_datasets(config), window, ("train",))
    ckpt.mkdir(parents=True, exist_ok=True)  # once there is something to train on
    train_f, val_f = split_validation(frames, config["val_params"], config.get("val_motions", ()))
    train_sets = len(np.unique(train_f.params))
    per_batch = config["invariant"]["sets_per_batch"]
    if not 2 <= per_batch <= train_sets:  # checked before the shape phase, not after it
        raise ValueError(f"invariant.sets_per_batch is {per_batch} but must be in [2, {train_sets}]: the loss "
                         f"divides by the variance between a batch's sets, and the training split holds "
                         f"{train_sets} parameter set(s)")
    log(f"{len(train_f)} training frames ({train_sets} parameter sets, "
        f"{len(np.unique(train_f.motions))} motions), {len(val_f)} validation frames "
        f"({len(np.unique(val_f.params))} sets, {len(np.unique(val_f.motions))} motions)")
    model = build_model(config, train_f)
    edges = edges_of(faces)
    summary: dict = {"config": config, "train_frames": len(train_f), "val_frames": len(val_f),
                     "train_sequences": _sequences(train_f), "val_sequences": _sequences(val_f),
                     "dataset_format": manifest.get("format"), "phases": {}}
    run = {"train_sequences": summary["train_sequences"], "val_sequences": summary["val_sequences"]}
    t0 = time.perf_counter()

    # phase 1: the shape autoencoder
    sc = config["shape"]
    opt = torch.optim.Adam(model.shape.parameters(), lr=sc["lr"])
    start, best = 0, (float("inf"), None)  # type: tuple[int, tuple[float, dict | None]]
    last = _latest(ckpt, "shape")
    if last is not None:
        state = _resume(last, run, config)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start, best = state["step"], state["best"]
        if "rng" in state:  # the batches the uninterrupted run drew after this step
            rng.bit_generator.state = state["rng"]
    verts = torch.as_tensor(train_f.vertices)
    for step in tqdm(range(start, sc["steps"]), desc="shape", initial=start, total=sc["steps"]):
        idx = torch.as_tensor(rng.integers(0, len(verts), sc["batch"]))
        v = verts[idx]
        pred = model.shape.decode(model.shape.encode(v))
        loss = ((pred - v) ** 2).sum(-1).mean() + sc["laplacian"] * uniform_laplacian_loss(pred, v, edges)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"shape step {step}: the loss is not finite; nothing exported")
        opt.zero_grad()
        loss.backward()
        opt.step()
        if (step + 1) % config["checkpoint_every"] == 0 or step + 1 == sc["steps"]:
            err = shape_error_mm(model, val_f)
            if err < best[0]:
                best = (err, {k: t.clone() for k, t in model.shape.state_dict().items()})
            save_whole({"model": model.state_dict(), "optimizer": opt.state_dict(), "step": step + 1,
                        "best": best, "rng": rng.bit_generator.state, "run": run, "config": json.dumps(config)},
                       ckpt / f"shape_{step + 1}.pt")
            log(f"shape step {step + 1}: validation vertex error {err:.2f} mm (best {best[0]:.2f})")
    if best[1] is not None:
        model.shape.load_state_dict(best[1])
    summary["phases"]["shape"] = {"steps": sc["steps"], "val_vertex_error_mm": best[0]}

    # phase 2: the motion-invariant autoencoder (N_E/N_D frozen)
    ic = config["invariant"]
    params = [p for name, p in model.named_parameters() if not name.startswith("shape.")]
    # optional regularisers (absent: the paper's plain Adam, bit-identical to runs before them):
    # weight_decay (AdamW's decoupled decay) and window_noise (metres: Gaussian noise on the motion windows'
    # joint positions, drawn per step from the seed and the step: the same run draws the same noise)
    wd, noise = float(ic.get("weight_decay", 0.0)), float(ic.get("window_noise", 0.0))
    opt = torch.optim.AdamW(params, lr=ic["lr"], weight_decay=wd) if wd > 0 else torch.optim.Adam(params, lr=ic["lr"])
    start, best = 0, (float("inf"), None)
    parts: dict = {}
    rng = np.random.default_rng(config["seed"])  # each phase its own batches: a run resumed here equals a fresh one
    last = _latest(ckpt, "invariant")
    if last is not None:
        state = _resume(last, run, config)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start, best, parts = state["step"], state["best"], state.get("parts", {})
        if "rng" in state:
            rng.bit_generator.state = state["rng"]
    by_set = {p: np.flatnonzero(train_f.params == p) for p in np.unique(train_f.params)}
    set_ids = np.array(sorted(by_set))
    wins = torch.as_tensor(train_f.windows)
    for step in tqdm(range(start, ic["steps"]), desc="invariant", initial=start, total=ic["steps"]):
        chosen = rng.choice(set_ids, ic["sets_per_batch"], replace=False)
        pick = np.concatenate([rng.choice(by_set[p], ic["frames_per_set"]) for p in chosen])
        w = wins[pick]
        if noise > 0:
            g = torch.Generator().manual_seed(config["seed"] * 1_000_003 + step)
            w = w + noise * torch.randn(w.shape, generator=g, dtype=w.dtype)
        loss, parts = invariant_loss(model, verts[pick], w, len(chosen), ic["lambda"], ic.get("set_lambda", 0.0))
        if not torch.isfinite(loss):
            raise FloatingPointError(f"invariant step {step}: the loss is not finite ({parts}); nothing exported")
        opt.zero_grad()
        loss.backward()
        opt.step()
        if (step + 1) % config["checkpoint_every"] == 0 or step + 1 == ic["steps"]:
            err = set_latent_error_mm(model, val_f)
            if err < best[0]:
                best = (err, {k: t.clone() for k, t in model.state_dict().items()})
            save_whole({"model": model.state_dict(), "optimizer": opt.state_dict(), "step": step + 1,
                        "best": best, "parts": parts, "rng": rng.bit_generator.state, "run": run,
                        "config": json.dumps(config)},
                       ckpt / f"invariant_{step + 1}.pt")
            log(f"invariant step {step + 1}: {parts}, validation set-latent vertex error {err:.2f} mm "
                f"(best {best[0]:.2f})")
    if best[1] is not None:
        model.load_state_dict(best[1])
    summary["phases"]["invariant"] = {"steps": ic["steps"], "val_set_latent_error_mm": best[0], "last": parts}
    summary["seconds"] = round(time.perf_counter() - t0, 1)
    done = ckpt / "best.pt"
    if start == ic["steps"] and done.exists():  # nothing left to train: the run that trained it took its time
        summary["seconds"] = torch.load(done, weights_only=False)["summary"].get("seconds", summary["seconds"])
    summary["latent_mean"], summary["latent_std"] = latent_statistics(model, train_f)
    save_whole({"model": model.state_dict(), "config": config, "model_config": model.cfg.to_dict(),
                "summary": summary, "faces": faces}, ckpt / "best.pt")
    return model, summary


@torch.no_grad()
def latent_statistics(model: IntrinsicSpace, frames: Frames) -> tuple[list[float], list[float]]:
    """Mean and standard deviation, per latent dimension, of the parameter sets' mean latents: (Z,), (Z,).
    `sample` draws design candidates from them."""
    means = []
    for p in np.unique(frames.params):
        f = frames.subset(frames.params == p)
        means.append(model.encode(torch.as_tensor(f.vertices), torch.as_tensor(f.windows)).mean(dim=0))
    m = torch.stack(means)
    return m.mean(dim=0).tolist(), m.std(dim=0).tolist()


def export_trained(model: IntrinsicSpace, summary: dict, out: str | Path) -> list[Path]:
    """The trained model -> the folder the service serves (drape/assets/models/intrinsic/<template>):
    the template (the dataset's `<template>.obj`, the rest shape it was simulated from), the body and
    fps of the dataset, the latent statistics and the training summary."""
    from drape.export.intrinsic import export_intrinsic
    from drape.geometry.mesh_io import load_mesh

    config = summary["config"]
    dataset = Path(config["dataset"])
    manifest = json.loads((dataset / "manifest.json").read_text())
    rest, faces = load_mesh(dataset / f"{config['template']}.obj")
    with np.load(dataset / manifest["items"][0]["file"], allow_pickle=False) as z:
        fps = float(z["fps"])
    training = {k: v for k, v in summary.items() if k not in ("latent_mean", "latent_std")}
    return export_intrinsic(model, out, template=config["template"], rest_vertices=rest, faces=faces,
                            body=manifest["body"], fps=fps, latent_mean=np.asarray(summary["latent_mean"]),
                            latent_std=np.asarray(summary["latent_std"]), extra={"training": training})
