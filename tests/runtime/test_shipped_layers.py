"""The shipped inner-layer networks (drape/assets/models/mgn_inner/<inner>/): what the manifest says is what is
served, and the network is the served template's."""

import numpy as np
import pytest

from drape.assets.motion import load_clip
from drape.runtime.layers import INNER_MODELS, LayerCatalog, load_inner_model

SHIPPED = sorted(p.name for p in INNER_MODELS.iterdir() if (p / "manifest.json").exists()) if INNER_MODELS.exists() else []


@pytest.fixture(scope="module")
def catalog():
    return LayerCatalog()


@pytest.mark.parametrize("name", SHIPPED)
def test_the_served_model_is_the_one_that_measured_better_on_validation(name, catalog):
    net = load_inner_model(name)
    m = net.manifest
    better = m["validation"]["score"] < m["deepsd_validation"]["score"]
    assert m["served"] == ("mgn_inner" if better else "deepsd") and net.served == better
    assert m["validation"]["score"] == min(v["score"] for v in m["validation_steps"].values())  # chosen on validation
    template = catalog.template(name)  # the catalog checks the network's template against the served one
    assert template.model == ("mgn_inner" if better else "deepsd")
    assert {"steps", "seconds", "wall_seconds", "machine"} <= set(m["training"])


@pytest.mark.parametrize("name", SHIPPED)
def test_the_network_keeps_the_garment_on_its_template_s_scale(name):
    """Posed along a clip none of its training saw, the offsets stay within a few centimetres and finite."""
    net = load_inner_model(name)
    clip = load_clip("dance_b")
    keys = net.pose_keys(clip.poses)
    offsets = np.einsum("tk,knc->tnc", keys, net.rig.blend_shapes)
    assert np.isfinite(offsets).all() and np.abs(offsets).max() < 0.15
    assert np.allclose(net.rig.weights.sum(1), 1, atol=1e-5)
