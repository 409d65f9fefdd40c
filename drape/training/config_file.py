"""A training config file: one JSON object, read once here for every network's trainer and evaluator."""

from __future__ import annotations

import difflib
import json
from collections.abc import Callable, Collection, Mapping
from pathlib import Path

CONFIGS = Path(__file__).parent / "configs"  # the committed configs, <kind>_<name>.json

# The settings each kind of config may hold: a name -> None (a value the trainer reads whole), the names its JSON
# object may hold, or a function giving them (the keywords of what the object is passed to: a model's config
# dataclass, read only when needed, as it imports torch). Each trainer reads these and no others, so a misspelt
# name would train with the default without a word; `check_settings` makes it an error before anything runs. A
# new setting goes here and in the trainer.
SET_BY_THE_TRAINER = {"num_vertices", "num_inner_keys", "parents"}  # what the code passes beside the config's


def _fields(module: str, name: str) -> set[str]:
    """A config dataclass's fields the config may set."""
    import dataclasses
    import importlib

    return {f.name for f in dataclasses.fields(getattr(importlib.import_module(module), name))} - SET_BY_THE_TRAINER


def _keywords(module: str, name: str, skip: int) -> set[str]:
    """A function's parameters after the first `skip` the config may set."""
    import importlib
    import inspect

    names = list(inspect.signature(getattr(importlib.import_module(module), name)).parameters)
    return set(names[skip:]) - SET_BY_THE_TRAINER


Names = Collection[str] | Callable[[], Collection[str]] | None
SETTINGS: dict[str, dict[str, Names]] = {
    "deepsd": {
        "batch_frames": None, "bodies": None, "checkpoint_every": None, "eval_frames_per_clip": None,
        "eval_outfits": None, "eval_vertices": None, "heldout_clips": None, "init_checkpoints": None,
        "joint_candidates": lambda: _keywords("drape.geometry.queries", "candidate_joints", skip=3),
        "loose_prior_share": None,
        "loss": {"bend", "blend_l2", "collision", "edge", "eps", "follow", "follow_margin", "prior_blend",
                 "prior_weights", "prior_weights_near", "prior_weights_physics"},
        "loss_phase": None,  # phase -> loss weights, checked by training.deepsd.phase_loss_weights
        "lr": None,
        "mocap": {"dir", "flips", "fps", "train"},
        "pose_noise": None, "procedural_frames": None, "procedural_motions": None,
        "procedural_posture": {"motions", "posture"},
        "procedural_spread": {"motions", "spread"},
        "seed": None,
        "steps": {"chi", "physics", "prior"},
        "train_outfits": None,
        "train_oversize": {"looseness", "outfits", "types"},
        "train_types": None, "train_vertices": None,
        "validation": {"clips", "frames_per_clip", "influences", "max_weights_off_prior_pct", "outfit_seed",
                       "oversize", "procedural_frames", "procedural_seeds", "procedural_spread", "steps"},
    },
    "intrinsic": {
        "checkpoint_every": None, "dataset": None, "extra_datasets": None,
        "invariant": {"frames_per_set", "lambda", "lr", "set_lambda", "sets_per_batch", "steps", "weight_decay",
                      "window_noise"},
        "model": lambda: _fields("drape.models.intrinsic", "IntrinsicConfig"),
        "seed": None,
        "shape": {"batch", "laplacian", "lr", "steps"},
        "template": None, "val_motions": None, "val_params": None,
    },
    "mgn_inner": {
        "batch_frames": None, "body": None,
        "collision_fit": {"gain", "stride", "real_frames"},
        "heldout_clips": None, "inner": None,
        "loss": {"bend", "collision", "edge", "eps", "gravity", "offset_l2"},
        "lr": None,
        "mocap": {"dir", "fps", "train"},
        "model": lambda: _fields("drape.models.layers", "InnerConfig"),
        "outfit_seed": None, "pair": None, "pose_noise": None, "procedural_frames": None, "procedural_motions": None,
        "seed": None, "steps": None, "validate_every": None,
        "validation": {"clips", "frames_per_clip", "procedural_frames", "procedural_seeds"},
        "vertices": None, "weights_k": None,
    },
    "mgn_outer": {
        "batch_windows": None, "body": None, "body_triangles": None, "candidates": None, "cover": None, "data": None,
        "inner": None,
        "loss": {"body", "body_frames", "edge", "eps", "eps_body", "laplacian", "margin_thickness", "repulsion", "temporal",
                 "vertex"},
        "loss_frames": None, "lr": None, "max_clip_h_coll_pct": None, "max_clip_l_coll_pct": None,
        "max_h_coll_pct": None, "max_l_coll_pct": None,
        "mocap": {"dir", "embedded", "flips", "fps", "loss", "loss_frames", "max_frames", "train", "validation",
                  "validation_frames", "windows"},
        "model": lambda: _fields("drape.models.layers", "OuterConfig"),
        "outer": None, "outfit_seed": None, "pair": None, "seed": None, "steps": None, "target_follows_inner": None,
        "target_refined": None, "thickness": None, "tolerated_checks": None, "train_items": None,
        "validate_every": None, "vertices": None, "warmup": None, "weight_decay": None, "weights_k": None,
    },
}


def _unknown(name: str, known: Collection[str]) -> str:
    near = difflib.get_close_matches(name, list(known), n=1)
    return f"unknown setting {name!r}" + (f" (did you mean {near[0]!r}?)" if near else "")


def check_settings(config: Mapping, kind: str, where: str | Path) -> None:
    """ValueError naming `where` and the first setting of `config` a `kind` config (a key of SETTINGS) may not
    hold, at the top level or one level down, with the nearest known name."""
    schema: Mapping[str, Names] = SETTINGS[kind]
    for name, value in config.items():
        if name not in schema:
            raise ValueError(f"{where}: {_unknown(name, schema)}; a {kind} config holds {', '.join(sorted(schema))}")
        inner = schema[name]
        inner = inner() if callable(inner) else inner
        if inner is not None and isinstance(value, Mapping):
            for sub in value:
                if sub not in inner:
                    raise ValueError(f"{where}: {name}: {_unknown(sub, inner)}; {name} holds {', '.join(sorted(inner))}")


def read_config(path: str | Path, kind: str | None = None) -> dict:
    """The JSON object in `path`; ValueError naming the file for anything else (not JSON, a list) or, given the
    config's `kind` (a key of SETTINGS), for a setting it may not hold; OSError for a file that cannot be read."""
    p = Path(path)
    try:
        config = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: is not JSON: {exc}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{p}: is not JSON text (UTF-8)") from None
    if not isinstance(config, dict):
        raise ValueError(f"{p}: a config is a JSON object of settings, got {type(config).__name__}")
    if kind is not None:
        check_settings(config, kind, p)
    return config


def named_config(kind: str, name: str, option: str) -> dict:
    """The committed config `<kind>_<name>.json` (e.g. intrinsic_skirt, mgn_inner_tshirt); a name with none is a
    ValueError naming `option` and the names there are (it was an OSError about the config's path)."""
    path = CONFIGS / f"{kind}_{name}.json"
    if not path.is_file():
        known = sorted(p.stem[len(kind) + 1:] for p in CONFIGS.glob(f"{kind}_*.json"))
        raise ValueError(f"{option} {name!r}: no committed config {path.name}; configs of {kind}: {', '.join(known)}")
    return read_config(path, kind)
