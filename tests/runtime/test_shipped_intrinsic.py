"""The shipped intrinsic networks (drape/assets/models/intrinsic/<template>/): each is what its committed config
trains."""

import json

import pytest

from drape.runtime.intrinsic import INTRINSIC_DIR
from drape.training.intrinsic import load_config

SHIPPED = sorted(p.name for p in INTRINSIC_DIR.iterdir() if (p / "manifest.json").exists()) if INTRINSIC_DIR.exists() else []


@pytest.mark.parametrize("template", SHIPPED)
def test_the_committed_config_is_the_one_the_shipped_network_was_trained_with(template):
    """`drape train intrinsic --template T` reads drape/training/configs/intrinsic_T.json: it must be the
    manifest's config, or the one command no longer reproduces what ships."""
    manifest = json.loads((INTRINSIC_DIR / template / "manifest.json").read_text())
    assert manifest["training"]["config"] == load_config(template)
