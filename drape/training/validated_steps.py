"""Checkpoints of a training run chosen on a validation split (the layer networks' loops): every measured step
is saved with its optimiser, the validation record, torch's random state (dropout: a resumed run draws what
the uninterrupted one would), the config and the sequences it trains and validates on (`data`), the best-scoring
step's weights also as `best.pt` (a NaN score, a diverged network, is never the best); a run resumes from the
latest step, only where that was saved by a run of the same config on the same sequences, and ends on the best
one. Files under the run's checkpoint folder (git-ignored).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path

import torch


def resume(ckpt_dir: Path, model: torch.nn.Module, opt: torch.optim.Optimizer, record: dict,
           log: Callable[[str], object], cfg: dict, data: dict[str, list[str]] | None = None,
           ) -> tuple[int, float, dict]:
    """Load the latest step_*.pt into model and opt -> (steps done, seconds elapsed, record); (0, 0, record)
    where none exists. ValueError where it was saved by a run of another config than `cfg`, or on other sequences
    than `data` (check_same_data; resuming would mix two trainings, or take the other run's chosen network as
    this one's)."""
    found = sorted(ckpt_dir.glob("step_*.pt"))
    if not found:
        return 0, 0.0, record
    state = torch.load(found[-1], weights_only=True)
    check_same_config(json.loads(state["config"]), cfg, found[-1])
    if data is not None:
        if "data" in state:
            check_same_data(json.loads(state["data"]), data, found[-1])
        else:  # saved before checkpoints recorded their sequences: taken, the steps from here on record them
            log(f"{found[-1].name} does not record the sequences it was trained on (an older checkpoint): "
                f"resuming without checking them")
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


def check_same_data(saved: dict, data: dict, path: Path) -> None:
    """ValueError naming the sequences added and gone, per split, where a checkpoint's `saved` sequences
    ({split: [identifiers]}) are not `data`'s: the dataset grew (make layers-data), or the split changed."""
    differ = []
    for split in sorted(set(saved) | set(data)):
        old, new = set(saved.get(split, [])), set(data.get(split, []))
        if old != new:
            differ.append(f"{split}: {_names(new - old)} added, {_names(old - new)} gone")
    if differ:
        raise ValueError(f"{path.parent}: {path.name} was trained on other sequences ({'; '.join(differ)}): resuming "
                         f"would mix two trainings' data and keep a step chosen on another validation split; delete "
                         f"the folder or give this run its own (--checkpoints)")


def _names(keys: set[str], most: int = 5) -> str:
    shown = sorted(keys)[:most]
    return f"{shown}" + (f" and {len(keys) - most} more" if len(keys) > most else "")


def save_whole(state: dict, path: Path) -> None:
    """torch.save through a temporary file renamed into place (every trainer's checkpoints): a run killed
    mid-save leaves the checkpoints before it whole, and no truncated file for the rerun's torch.load to fail on."""
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def best_step(record: dict) -> str:
    """The step of record["steps"] with the lowest score (the first of equals); NaN scores rank last."""
    steps = record["steps"]
    return min(steps, key=lambda k: math.inf if math.isnan(steps[k]["score"]) else steps[k]["score"])


def save_step(ckpt_dir: Path, model: torch.nn.Module, opt: torch.optim.Optimizer, done: int, elapsed: float,
              record: dict, cfg: dict, data: dict[str, list[str]] | None = None) -> None:
    """After record["steps"][str(done)] was measured: best.pt where it scores lowest so far, and step_<done>.pt
    (with `data`, the sequences the run trains and validates on, where given: resume checks them)."""
    if best_step(record) == str(done):
        save_whole({"model": model.state_dict(), "step": done}, ckpt_dir / "best.pt")
    state = {"model": model.state_dict(), "opt": opt.state_dict(), "done": done, "elapsed": elapsed,
             "record": json.dumps(record), "config": json.dumps(cfg), "rng": torch.get_rng_state()}
    if data is not None:
        state["data"] = json.dumps(data)
    save_whole(state, ckpt_dir / f"step_{done:07d}.pt")


def restore_best(ckpt_dir: Path, model: torch.nn.Module, record: dict) -> str:
    """Load best.pt into model (eval mode), record["chosen"], write validation.json -> the chosen step."""
    best = best_step(record)
    record["chosen"] = int(best)
    model.load_state_dict(torch.load(ckpt_dir / "best.pt", weights_only=True)["model"])
    model.eval()
    (ckpt_dir / "validation.json").write_text(json.dumps(record, indent=2) + "\n")
    return best
