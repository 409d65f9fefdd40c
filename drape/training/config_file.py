"""A training config file: one JSON object, read once here for every network's trainer and evaluator."""

from __future__ import annotations

import json
from pathlib import Path

CONFIGS = Path(__file__).parent / "configs"  # the committed configs, <kind>_<name>.json


def read_config(path: str | Path) -> dict:
    """The JSON object in `path`; ValueError naming the file for anything else (not JSON, a list), OSError for a
    file that cannot be read."""
    p = Path(path)
    try:
        config = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: is not JSON: {exc}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{p}: is not JSON text (UTF-8)") from None
    if not isinstance(config, dict):
        raise ValueError(f"{p}: a config is a JSON object of settings, got {type(config).__name__}")
    return config


def named_config(kind: str, name: str, option: str) -> dict:
    """The committed config `<kind>_<name>.json` (e.g. intrinsic_skirt, mgn_inner_tshirt); a name with none is a
    ValueError naming `option` and the names there are (it was an OSError about the config's path)."""
    path = CONFIGS / f"{kind}_{name}.json"
    if not path.is_file():
        known = sorted(p.stem[len(kind) + 1:] for p in CONFIGS.glob(f"{kind}_*.json"))
        raise ValueError(f"{option} {name!r}: no committed config {path.name}; configs of {kind}: {', '.join(known)}")
    return read_config(path)
