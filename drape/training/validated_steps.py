"""Checkpoints of a training run chosen on a validation split (the layer networks' loops): every measured step
is saved with its optimiser and the validation record, the best-scoring step's weights also as `best.pt`; a run
resumes from the latest step and ends on the best one. Files under the run's checkpoint folder (git-ignored).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import torch


def resume(ckpt_dir: Path, model: torch.nn.Module, opt: torch.optim.Optimizer, record: dict,
           log: Callable[[str], object]) -> tuple[int, float, dict]:
    """Load the latest step_*.pt into model and opt -> (steps done, seconds elapsed, record); (0, 0, record)
    where none exists."""
    found = sorted(ckpt_dir.glob("step_*.pt"))
    if not found:
        return 0, 0.0, record
    state = torch.load(found[-1], weights_only=True)
    model.load_state_dict(state["model"])
    opt.load_state_dict(state["opt"])
    log(f"resuming from {found[-1].name}")
    return int(state["done"]), float(state["elapsed"]), json.loads(state["record"])


def save_step(ckpt_dir: Path, model: torch.nn.Module, opt: torch.optim.Optimizer, done: int, elapsed: float,
              record: dict, cfg: dict) -> None:
    """After record["steps"][str(done)] was measured: best.pt where it scores lowest so far, and step_<done>.pt."""
    if min(record["steps"], key=lambda k: record["steps"][k]["score"]) == str(done):
        torch.save({"model": model.state_dict(), "step": done}, ckpt_dir / "best.pt")
    torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "done": done, "elapsed": elapsed,
                "record": json.dumps(record), "config": json.dumps(cfg)}, ckpt_dir / f"step_{done:07d}.pt")


def restore_best(ckpt_dir: Path, model: torch.nn.Module, record: dict) -> str:
    """Load best.pt into model (eval mode), record["chosen"], write validation.json -> the chosen step."""
    best = min(record["steps"], key=lambda k: record["steps"][k]["score"])
    record["chosen"] = int(best)
    model.load_state_dict(torch.load(ckpt_dir / "best.pt", weights_only=True)["model"])
    model.eval()
    (ckpt_dir / "validation.json").write_text(json.dumps(record, indent=2) + "\n")
    return best
