"""The shipped layer networks (drape/assets/models/mgn_inner/<inner>/, mgn_outer/<inner>_<outer>/): what the
manifest says is what is served, and the network is the served template's."""

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.runtime.layers import (
    INNER_MODELS,
    OUTER_MODELS,
    LayerCatalog,
    load_inner_model,
    load_outer_model,
)
from drape.training import layers_inner, layers_outer
from drape.training.layers_eval import CLIP, REAL


def _shipped(folder):
    return sorted(p.name for p in folder.iterdir() if (p / "manifest.json").exists()) if folder.exists() else []


SHIPPED = _shipped(INNER_MODELS)
SHIPPED_OUTER = _shipped(OUTER_MODELS)


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
def test_the_committed_config_is_the_one_the_shipped_inner_network_was_trained_with(name):
    """`drape train mgn-inner --inner NAME` reads drape/training/configs/mgn_inner_NAME.json: it must be the
    config in the manifest, or the one command no longer reproduces what ships."""
    assert load_inner_model(name).manifest["config"] == layers_inner.load_config(name)


@pytest.mark.parametrize("name", SHIPPED)
def test_the_inner_rigs_collision_fit_serves_only_where_it_measured_better_on_validation(name):
    """`drape train mgn-inner-fit` (drape.training.layers_inner_fit): the fitted rig serves where its validation
    score is lower than the network's own rig's; that figure is the network's validation (measured again)."""
    m = load_inner_model(name).manifest
    if "collision_fit" not in m:
        pytest.skip("no collision fit recorded")
    fit = m["collision_fit"]
    better = fit["validation_fitted"]["score"] < fit["validation_network"]["score"]
    assert fit["served"] == ("fitted" if better else "network")
    assert abs(fit["validation_network"]["score"] - m["validation"]["score"]) < 0.01
    assert fit["settings"] == m["config"]["collision_fit"]


@pytest.mark.parametrize("pair", SHIPPED_OUTER)
def test_the_committed_config_is_the_one_the_shipped_outer_network_was_trained_with(pair):
    """As above, for `drape train mgn-outer --outer OUTER` and drape/training/configs/mgn_outer_OUTER.json."""
    inner, outer = pair.split("_")
    assert load_outer_model(inner, outer).manifest["config"] == layers_outer.load_config(outer)


@pytest.mark.parametrize("name", SHIPPED)
def test_the_network_keeps_the_garment_on_its_template_s_scale(name):
    """Posed along a clip none of its training saw, the offsets stay within a few centimetres and finite."""
    net = load_inner_model(name)
    clip = load_clip("dance_b")
    keys = net.pose_keys(clip.poses)
    offsets = np.einsum("tk,knc->tnc", keys, net.rig.blend_shapes)
    assert np.isfinite(offsets).all() and np.abs(offsets).max() < 0.15
    assert np.allclose(net.rig.weights.sum(1), 1, atol=1e-5)


@pytest.mark.parametrize("pair", SHIPPED_OUTER)
def test_the_served_outer_model_is_the_one_that_measured_better_beside_the_shipped_inner(pair, catalog):
    inner, outer = pair.split("_")
    net = load_outer_model(inner, outer)
    m = net.manifest
    better = m["validation"]["score"] < m["deepsd_validation"]["score"]
    assert m["served"] == ("mgn_outer" if better else "deepsd") and net.served == better
    assert m["validation"]["score"] == min(v["score"] for v in m["validation_steps"].values())  # chosen on validation
    assert net.inner_sha256 == load_inner_model(inner).sha256  # trained beside the inner network that ships
    c = catalog.find(inner, outer)
    assert c.outer.model == ("mgn_outer" if better else "deepsd")
    assert sorted(m["training"]["data"]["train"]) == sorted(m["config"]["train_items"])  # what the config names
    clips, held = m["training"]["data"].get("clips", []), m["training"]["data"].get("clip_validation", [])
    assert {REAL.stem, CLIP}.isdisjoint(clips + held) and not set(clips) & set(held)  # the evaluation's: never seen
    assert {"steps", "seconds", "wall_seconds", "machine"} <= set(m["training"])


@pytest.mark.parametrize("pair", SHIPPED_OUTER)
def test_the_outer_network_keeps_the_garment_on_its_template_s_scale(pair):
    """Along a clip none of its training saw, at both ends of its thickness range: offsets finite, within
    centimetres, and the thickness changes them."""
    inner, outer = pair.split("_")
    net, inner_net = load_outer_model(inner, outer), load_inner_model(inner)
    clip = load_clip("dance_b")
    joints = load_body(net.manifest["body"]).joints
    low, high = net.thickness
    keys = [net.pose_keys(clip.poses, clip.trans, clip.fps, h, inner_net.pose_keys(clip.poses), joints)
            for h in (low, high)]
    offsets = [np.einsum("tk,knc->tnc", k, net.rig.blend_shapes) for k in keys]
    assert all(np.isfinite(o).all() and np.abs(o).max() < 0.3 for o in offsets)
    assert np.abs(offsets[0] - offsets[1]).max() > 1e-4
