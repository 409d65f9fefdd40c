"""DeePSD networks against their ONNX exports (a freshly initialised model)."""

import numpy as np
import onnxruntime as ort
import pytest
import torch

from drape.assets.outfits import generate_outfit
from drape.export.deepsd import export_deepsd
from drape.models.deepsd import DeployedOutfitNet, OutfitNet, PoseNet
from drape.runtime.deepsd import network_inputs


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(0)
    outfit, pose = OutfitNet(), PoseNet()
    paths = export_deepsd(outfit, pose, tmp_path_factory.mktemp("deepsd"))
    return outfit, pose, paths


def _parity(exported, n, seed):
    outfit, _, paths = exported
    o = generate_outfit("tshirt,trousers", vertices=n, seed=seed)
    inputs = network_inputs(o.vertices, o.faces)
    sess = ort.InferenceSession(str(paths["outfit"]), providers=["CPUExecutionProvider"])
    w, d, dd = sess.run(None, inputs)
    with torch.no_grad():
        tw, td, tdd = DeployedOutfitNet(outfit)(*(torch.from_numpy(inputs[k]) for k in ("features", "nbr_idx", "nbr_w")))
    assert w.shape == (len(o.vertices), 24) and d.shape == (128, len(o.vertices), 3)
    assert np.abs(w - tw.numpy()).max() <= 1e-4
    assert np.abs(d - td.numpy()).max() <= 1e-4 and np.abs(dd - tdd.numpy()).max() <= 1e-4


@pytest.mark.parametrize("n", [1000, 10000])
def test_outfit_network_matches_torch(exported, n):
    _parity(exported, n, seed=n)


@pytest.mark.slow
def test_outfit_network_matches_torch_30k(exported):
    _parity(exported, 30000, seed=3)


def test_pose_network_matches_torch_any_length(exported):
    _, pose, paths = exported
    sess = ort.InferenceSession(str(paths["pose"]), providers=["CPUExecutionProvider"])
    for t in (1, 7, 300):
        p = np.random.default_rng(t).normal(scale=0.5, size=(t, 72)).astype(np.float32)
        keys = sess.run(None, {"poses": p})[0]
        with torch.no_grad():
            ref = pose(torch.from_numpy(p)).numpy()
        assert keys.shape == (t, 128) and np.abs(keys - ref).max() <= 1e-5
        assert np.allclose(keys.sum(1), 1.0, atol=1e-5)


def test_rig_is_permutation_equivariant(exported):
    """Shuffling an outfit's vertex order permutes its rig the same way (any topology order)."""
    _, _, paths = exported
    o = generate_outfit("skirt", vertices=1500, seed=4)
    perm = np.random.default_rng(0).permutation(len(o.vertices))
    inv = np.argsort(perm)
    sess = ort.InferenceSession(str(paths["outfit"]), providers=["CPUExecutionProvider"])
    w, d, _ = sess.run(None, network_inputs(o.vertices, o.faces))
    wp, dp, _ = sess.run(None, network_inputs(o.vertices[perm], inv[o.faces]))
    assert np.abs(wp - w[perm]).max() < 1e-5
    assert np.abs(dp - d[:, perm]).max() < 1e-5
