"""Checkpoints of a training run chosen on a validation split (the layer networks' loops): every measured step
is saved with its optimiser, the validation record and torch's random state (dropout: a resumed run draws what
the uninterrupted one would), the best-scoring step's weights also as `best.pt` (a NaN score, a diverged
network, is never the best); a run resumes from the latest step and ends on the best one. Files under the run's
checkpoint folder (git-ignored).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import torch


def resume(ckpt_dir: Path, model: torch.nn.Module, opt: torch.optim.Optimizer, record: dict,
           log: Callable[[str], object], cfg: dict) -> tuple[int, float, dict]:
    """Load the latest step_*.pt into model and opt -> (steps done, seconds elapsed, record); (0, 0, record)
    where none exists. ValueError where it was saved by a run of another config than `cfg` (resuming would mix
    two trainings, or take the other run's chosen network as this one's)."""
    found = sorted(ckpt_dir.glob("step_*.pt"))
    if not found:
        return 0, 0.0, record
    state = torch.load(found[-1], weights_only=True)
    check_same_config(json.loads(state["config"]), cfg, found[-1])
    model.load_state_dict(state["model"])
    opt.load_state_dict(state["opt"])
    if "rng" in state:  # older checkpoints did not keep it
        torch.set_rng_state(state["rng"])
    log(f"resuming from {found[-1].name}")
    return int(state["done"]), float(state["elapsed"]), json.loads(state["record"])


def check_same_config(saved: dict, cfg: dict, path: Path) -> None:
    """ValueError naming the settings that differ where a checkpoint's config `saved` is not `cfg`."""
    cfg = json.loads(json.dumps(cfg))  # as a checkpoint records it (tuples as lists)
    if saved != cfg:
        keys = sorted(k for k in set(saved) | set(cfg) if saved.get(k) != cfg.get(k))
        raise ValueError(f"{path} is a checkpoint of another config (settings {keys} differ): resuming would mix "
                         f"two trainings; give this config its own checkpoint folder (--checkpoints)")


def best_step(record: dict) -> str:
    """The step of record["steps"] with the lowest score (the first of equals); NaN scores rank last."""
    steps = record["steps"]
    return min(steps, key=lambda k: math.inf if math.isnan(steps[k]["score"]) else steps[k]["score"])


def save_step(ckpt_dir: Path, model: torch.nn.Module, opt: torch.optim.Optimizer, done: int, elapsed: float,
              record: dict, cfg: dict) -> None:
    """After record["steps"][str(done)] was measured: best.pt where it scores lowest so far, and step_<done>.pt."""
    if best_step(record) == str(done):
        torch.save({"model": model.state_dict(), "step": done}, ckpt_dir / "best.pt")
    torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "done": done, "elapsed": elapsed,
                "record": json.dumps(record), "config": json.dumps(cfg),
                "rng": torch.get_rng_state()}, ckpt_dir / f"step_{done:07d}.pt")


def restore_best(ckpt_dir: Path, model: torch.nn.Module, record: dict) -> str:
    """Load best.pt into model (eval mode), record["chosen"], write validation.json -> the chosen step."""
    best = best_step(record)
    record["chosen"] = int(best)
    model.load_state_dict(torch.load(ckpt_dir / "best.pt", weights_only=True)["model"])
    model.eval()
    (ckpt_dir / "validation.json").write_text(json.dumps(record, indent=2) + "\n")
    return best
