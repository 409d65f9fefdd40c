"""The shipped (trained) DeePSD: manifest integrity, size, and consistency across topologies."""

import json
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from drape.assets.body import load_body
from drape.assets.outfits import generate_outfit
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel
from drape.training.config_file import read_config

pytestmark = pytest.mark.skipif(not (MODEL_DIR / "manifest.json").exists(), reason="no shipped model")


@pytest.fixture(scope="module")
def model():
    return DeePSDModel(MODEL_DIR)


def test_the_makefile_s_config_is_the_one_the_shipped_model_was_trained_with():
    """`make deepsd-model` trains from the Makefile's DEEPSD_CONFIG: it must be the manifest's config (less the
    `_checkpoint` record the export adds), or the one command no longer reproduces what ships."""
    root = Path(__file__).resolve().parents[2]
    path = re.search(r"^DEEPSD_CONFIG \?= (\S+)$", (root / "Makefile").read_text(), re.M)
    assert path, "the Makefile names no DEEPSD_CONFIG"
    config = dict(json.loads((MODEL_DIR / "manifest.json").read_text())["training"]["config"])
    config.pop("_checkpoint", None)
    assert config == read_config(root / path.group(1))


def test_manifest_is_trained_small_and_evaluated(model):
    m = json.loads((MODEL_DIR / "manifest.json").read_text())
    assert m["trained"] is True and m["training"]["config"]["steps"]
    assert sum(f["bytes"] for f in m["files"].values()) <= 10 * 2**20
    from drape.training.deepsd_eval import METHODS

    assert m["evaluation"] and {r["method"] for r in m["evaluation"]["rows"]} == set(METHODS)
    assert {"model", "served", "served8"} <= set(METHODS)  # the network's rig and the rigs the service serves


def test_two_resolutions_of_one_garment_get_consistent_weights(model):
    """Same shirt, two vertex counts (other topology and vertex order): weights agree at nearby points."""
    a = generate_outfit("tshirt", vertices=2000, seed=5, looseness=0.3, length=0.5)
    b = generate_outfit("tshirt", vertices=5000, seed=5, looseness=0.3, length=0.5)
    body = load_body("neutral")
    wa, wb = model.rig(a.vertices, a.faces, body).weights, model.rig(b.vertices, b.faces, body).weights
    _, near = cKDTree(b.vertices).query(a.vertices)
    l1 = np.abs(wa - wb[near]).sum(axis=1)
    assert np.median(l1) < 0.3, np.median(l1)
    assert np.mean(wa.argmax(1) == wb[near].argmax(1)) > 0.8
