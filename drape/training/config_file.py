"""A training config file: one JSON object, read once here for every network's trainer and evaluator."""

from __future__ import annotations

import json
from pathlib import Path


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
