"""The layer catalog and the engine with layer networks (untrained ones exported on the served tshirt and jacket
templates): which model poses each layer, and that the engine's streams are those networks'."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from drape.assets.body import load_body
from drape.assets.motion import Motion, load_clip, resample
from drape.assets.outfits import split_outfit
from drape.export.layers import export_inner, export_outer
from drape.export.onnx_export import sha256
from drape.geometry.character_space import motion_features
from drape.geometry.skeleton import PARENTS
from drape.models.layers import InnerConfig, InnerPSD, OuterConfig, OuterTransformer
from drape.runtime.deepsd import pose_outfit
from drape.runtime.engine import Engine
from drape.runtime.layers import (
    BODY,
    SEED,
    VERTICES,
    LayerCatalog,
    load_inner_model,
    load_outer_model,
)
from drape.training.layers_inner import body_weights


def _export(folder, pair="tshirt,jacket"):
    torch.manual_seed(1)
    (v, f), _ = split_outfit(pair, VERTICES, seed=SEED, body=BODY)
    model = InnerPSD(InnerConfig(num_vertices=len(v), num_basis=8, width=16, basis_init=0.005))
    export_inner(model, folder / pair.split(",")[0], vertices=v, faces=f, weights=body_weights(v, load_body(BODY), 4),
                 manifest={"served": "mgn_inner"})


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mgn_inner")
    _export(folder)
    return folder


def test_a_served_network_poses_the_inner_layer(models):
    catalog = LayerCatalog(models=models)
    c = catalog.find("tshirt", "jacket")
    assert c.inner.model == "mgn_inner" and c.outer.model == "deepsd" and c.model == "mgn_inner+deepsd"
    assert catalog.template("tshirt").info()["models"] == ["mgn_inner"]
    other = catalog.find("tanktop", "longsleeve")  # no network shipped for it here
    assert other.inner.network is None and other.model == "deepsd"


def test_a_network_that_measured_worse_is_not_served(models, tmp_path):
    for p in (models / "tshirt").iterdir():
        (tmp_path / "tshirt").mkdir(exist_ok=True)
        (tmp_path / "tshirt" / p.name).write_bytes(p.read_bytes())
    manifest = json.loads((tmp_path / "tshirt" / "manifest.json").read_text())
    manifest["served"] = "deepsd"
    (tmp_path / "tshirt" / "manifest.json").write_text(json.dumps(manifest))
    assert not load_inner_model("tshirt", tmp_path).served
    assert LayerCatalog(models=tmp_path).find("tshirt", "jacket").model == "deepsd"


def _on_another_template(src: Path, dst: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Copy the exported network folder src to dst with its rig.npz's template replaced by (vertices, faces) and
    the manifest's sha256 of rig.npz updated: a network exported on another template, without a second export."""
    shutil.copytree(src, dst)
    manifest = json.loads((dst / "manifest.json").read_text())
    entry = manifest["files"]["rig"]
    with np.load(dst / entry["file"]) as z:
        arrays = dict(z)
    arrays.update(vertices=vertices.astype(np.float32), faces=faces.astype(np.int32))
    rig = dst / entry["file"]
    with rig.open("wb") as out:
        np.savez(out, **arrays)
    entry.update(sha256=sha256(rig), bytes=rig.stat().st_size)
    (dst / "manifest.json").write_text(json.dumps(manifest))


def test_a_network_of_another_template_is_refused(models, tmp_path):
    (v, f), _ = split_outfit("tshirt,jacket", VERTICES, seed=SEED + 1, body=BODY)
    _on_another_template(models / "tshirt", tmp_path / "tshirt", v, f)
    with pytest.raises(ValueError, match="another template"):
        LayerCatalog(models=tmp_path).combinations()


def test_the_engine_s_inner_stream_is_the_network_s(models):
    engine = Engine(refine_workers=1)
    try:
        engine.layers = LayerCatalog(models=models)
        c = engine.layers.find("tshirt", "jacket")
        clip = load_clip("dance_b")
        poses, trans = clip.poses[:40].astype(np.float64), clip.trans[:40].astype(np.float64)
        parts = list(engine.layer_chunks(c, 0.006, poses, trans, chunk=16))
        inner = np.concatenate([p[0] for p in parts])
        outer = np.concatenate([p[1] for p in parts])
        net = c.inner.network
        ref = pose_outfit(c.inner.vertices, net.rig, net.pose_keys(poses), load_body(BODY).joints, poses, trans)
        assert inner.shape == ref.shape and np.abs(inner - ref).max() <= 1e-5
        rig = engine.rig(c.outer.vertices, c.outer.faces, BODY)
        assert np.abs(outer - np.concatenate(list(engine.pose_chunks(rig, poses, trans)))).max() <= 1e-5
        # the untrained basis moves the cloth: not the template skinned alone
        skinned = pose_outfit(c.inner.vertices, net.rig, np.zeros_like(net.pose_keys(poses)), load_body(BODY).joints,
                              poses, trans)
        assert np.abs(inner - skinned).max() > 1e-3
    finally:
        engine.close()


def _export_outer(folder, inner_sha256):
    torch.manual_seed(2)
    _, (v, f) = split_outfit("tshirt,jacket", VERTICES, seed=SEED, body=BODY)
    model = OuterTransformer(OuterConfig(num_vertices=len(v), num_inner_keys=8, num_basis=8, d_model=16,
                                         feedforward=32, window=10, basis_init=0.005))
    export_outer(model, folder / "tshirt_jacket", vertices=v, faces=f, weights=body_weights(v, load_body(BODY), 4),
                 manifest={"served": "mgn_outer", "inner_network": {"pose_sha256": inner_sha256},
                           "config": {"thickness": [0.004, 0.012]}})


@pytest.fixture(scope="module")
def outer_models(tmp_path_factory, models):
    folder = tmp_path_factory.mktemp("mgn_outer")
    _export_outer(folder, load_inner_model("tshirt", models).sha256)
    return folder


def test_an_outer_network_is_served_beside_the_inner_network_it_reads(models, outer_models, tmp_path):
    c = LayerCatalog(models=models, outer_models=outer_models).find("tshirt", "jacket")
    assert c.outer.model == "mgn_outer" and c.model == "mgn_inner+mgn_outer" and c.thickness == (0.004, 0.012)
    # trained beside another inner network (the same export, its manifest naming another): not served, the outer
    # is DeePSD's and the thickness range the default
    shutil.copytree(outer_models / "tshirt_jacket", tmp_path / "tshirt_jacket")
    manifest = json.loads((tmp_path / "tshirt_jacket" / "manifest.json").read_text())
    manifest["inner_network"]["pose_sha256"] = "another inner network"
    (tmp_path / "tshirt_jacket" / "manifest.json").write_text(json.dumps(manifest))
    c = LayerCatalog(models=models, outer_models=tmp_path).find("tshirt", "jacket")
    assert c.outer.model == "deepsd" and c.thickness == (0.002, 0.02)
    # without the inner network it reads: not served either
    empty = tmp_path / "none"
    assert LayerCatalog(models=empty, outer_models=outer_models).find("tshirt", "jacket").model == "deepsd"
    assert load_outer_model("tshirt", "jacket", outer_models).served


def test_an_outer_network_of_another_template_is_refused(models, outer_models, tmp_path):
    _, (v, f) = split_outfit("tshirt,jacket", VERTICES, seed=SEED + 1, body=BODY)
    _on_another_template(outer_models / "tshirt_jacket", tmp_path / "tshirt_jacket", v, f)
    with pytest.raises(ValueError, match="another template"):
        LayerCatalog(models=models, outer_models=tmp_path).combinations()


def test_the_engine_s_outer_stream_is_the_network_s(models, outer_models):
    engine = Engine(refine_workers=1)
    try:
        engine.layers = LayerCatalog(models=models, outer_models=outer_models)
        c = engine.layers.find("tshirt", "jacket")
        clip = load_clip("dance_b")
        poses, trans = clip.poses[:45].astype(np.float64), clip.trans[:45].astype(np.float64)
        outer = np.concatenate([p[1] for p in engine.layer_chunks(c, 0.008, poses, trans, chunk=16, fps=30.0)])
        net, inner = c.outer.network, c.inner.network
        joints = load_body(BODY).joints
        keys = net.pose_keys(poses, trans, 30.0, 0.008, inner.pose_keys(poses), joints)
        ref = pose_outfit(c.outer.vertices, net.rig, keys, joints, poses, trans)
        assert outer.shape == ref.shape and np.abs(outer - ref).max() <= 1e-5
        # the thickness reaches the network
        other = net.pose_keys(poses, trans, 30.0, 0.004, inner.pose_keys(poses), joints)
        assert np.abs(other - keys).max() > 1e-4
    finally:
        engine.close()


def test_an_outer_network_reads_a_motion_over_the_seconds_it_was_trained_on(models, outer_models):
    """Its windows are 30 frames at 30 fps (1 s): a motion at 60 fps is resampled to 30 fps first, so the same
    poses sent at 60 fps give, at their even frames, the 30 fps keys (before, a window read half a second)."""
    c = LayerCatalog(models=models, outer_models=outer_models).find("tshirt", "jacket")
    net, inner = c.outer.network, c.inner.network
    assert net.fps == 30.0
    joints = load_body(BODY).joints
    clip = load_clip("dance_b")
    poses, trans = clip.poses[:75].astype(np.float64), clip.trans[:75].astype(np.float64)
    fast = resample(Motion(poses, trans, 30.0), 60.0)
    assert fast.num_frames == 149
    p60, t60 = fast.poses.astype(np.float64), fast.trans.astype(np.float64)
    keys30 = net.pose_keys(poses, trans, 30.0, 0.008, inner.pose_keys(poses), joints)
    keys60 = net.pose_keys(p60, t60, 60.0, 0.008, inner.pose_keys(p60), joints)
    assert keys60.shape == (149, keys30.shape[1])
    assert np.abs(keys60[::2] - keys30).max() <= 1e-4
    # the odd frames lie between their neighbours' keys
    mid = 0.5 * (keys30[:-1] + keys30[1:])
    assert np.abs(keys60[1::2] - mid).max() <= 1e-4
    # read frame by frame (the network's window over half the seconds), the same poses answer other keys
    frame_by_frame = net.keys_of_features(motion_features(p60, t60, joints, PARENTS, 60.0), 0.008,
                                          inner.pose_keys(p60))
    assert np.abs(frame_by_frame[::2] - keys30).max() > 1e-3


def test_an_outer_network_runs_its_windows_in_batches_as_in_one(models, outer_models, monkeypatch):
    """A slow motion is many windows at 30 fps (a probe's 300 frames at 0.9 fps: 600): run at once they took 792 MB
    of ONNX Runtime's memory, in batches of OUTER_BATCH 306 MB; the keys are the same."""
    import drape.runtime.layers as layers

    net = LayerCatalog(models=models, outer_models=outer_models).find("tshirt", "jacket").outer.network
    rng = np.random.default_rng(0)
    features, inner_keys = rng.normal(size=(200, 78)).astype(np.float32), rng.normal(size=(200, 8)).astype(np.float32)
    assert len(layers.window_starts(200, net.window)[0]) == 39  # this test network's windows are 10 frames
    monkeypatch.setattr(layers, "OUTER_BATCH", 1000)
    whole = net.keys_of_features(features, 0.008, inner_keys)
    monkeypatch.setattr(layers, "OUTER_BATCH", 4)  # 10 calls of 3 or 4 windows
    assert np.abs(net.keys_of_features(features, 0.008, inner_keys) - whole).max() <= 1e-5


def test_the_engine_s_warm_up_builds_the_layer_catalog():
    """The first GET /v1/garments or /v1/layers built it (~4 s: templates generated, networks loaded), past a
    client's timeout on a busy machine; the warm-up (the app's start) builds it now."""
    engine = Engine(refine_workers=1)
    try:
        assert engine.layers._made is None
        engine.warm_up()
        assert engine.layers._made is not None and engine.layers.templates()
    finally:
        engine.close()
