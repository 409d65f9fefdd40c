"""Datasets, physics losses, trainers and the `drape train` command (needs the [train] extra)."""

from pathlib import Path

DEFAULT_DEEPSD_CONFIG = Path(__file__).parent / "configs" / "deepsd.json"
# the simulated dataset `make sim-dataset` writes; `drape eval deepsd` compares against it when present
DEFAULT_GROUND_TRUTH = Path("data") / "sim" / "skirt"
