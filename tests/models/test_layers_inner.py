"""MGN's inner-layer network: its ONNX export against torch, the runtime's posing against the training's torch
posing, and the folder the runtime loads (a freshly initialised model on a small generated inner layer)."""

import numpy as np
import pytest
import torch

from drape.assets.body import load_body
from drape.assets.outfits import split_outfit
from drape.export.layers import export_inner
from drape.models.layers import InnerConfig, InnerPSD
from drape.runtime.deepsd import pose_outfit
from drape.runtime.layers import InnerModel
from drape.training import physics
from drape.training.layers_inner import body_weights


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(0)
    (v, f), _ = split_outfit("tanktop,longsleeve", 1200, seed=3)
    model = InnerPSD(InnerConfig(num_vertices=len(v), num_basis=16, width=32, basis_init=0.01))
    body = load_body("neutral")
    w = body_weights(v, body, 4)
    out = tmp_path_factory.mktemp("mgn_inner")
    export_inner(model, out, vertices=v, faces=f, weights=w, manifest={"served": "mgn_inner"})
    return model, v, f, w, body, out


def test_pose_network_matches_torch_at_two_lengths(exported):
    model, *_, out = exported
    net = InnerModel(out)
    for t in (3, 240):
        p = np.random.default_rng(t).normal(scale=0.4, size=(t, 72)).astype(np.float32)
        with torch.no_grad():
            ref = model.coefficients(torch.from_numpy(p)).numpy()
        keys = net.pose_keys(p)
        assert keys.shape == (t, 16) and np.abs(keys - ref).max() <= 1e-4


def test_served_posing_equals_the_trained_one(exported):
    """The runtime (ORT keys, the batched posing of a rig) against the training's torch posing (offsets, FK,
    LBS): one network, two formulations."""
    model, v, _, w, body, out = exported
    net = InnerModel(out)
    poses = np.random.default_rng(1).normal(scale=0.3, size=(5, 24, 3)).astype(np.float32)
    trans = np.random.default_rng(2).normal(scale=0.1, size=(5, 3)).astype(np.float32)
    served = pose_outfit(net.vertices, net.rig, net.pose_keys(poses), body.joints, poses, trans)
    with torch.no_grad():
        pt = torch.from_numpy(poses)
        offsets = model(pt.reshape(5, 72))
        ref = physics.lbs(torch.from_numpy(v) + offsets, torch.from_numpy(w),
                          physics.skinning_transforms(pt, torch.from_numpy(body.joints).float()))
    ref = ref.numpy() + trans[:, None]
    assert np.abs(offsets.numpy()).max() > 1e-3  # the basis moves the garment: the comparison is not trivial
    assert np.abs(served - ref).max() <= 1e-4


def test_the_folder_is_checked_and_holds_the_template(exported, tmp_path):
    _, v, f, w, _, out = exported
    net = InnerModel(out)
    assert np.array_equal(net.vertices, v) and np.array_equal(net.faces, f) and net.served
    assert np.allclose(net.rig.weights.sum(1), 1, atol=1e-5) and net.rig.blend_shapes.shape == (16, len(v), 3)
    for p in out.iterdir():
        (tmp_path / p.name).write_bytes(p.read_bytes())
    blob = bytearray((tmp_path / "rig.npz").read_bytes())
    blob[-10] ^= 1
    (tmp_path / "rig.npz").write_bytes(bytes(blob))
    with pytest.raises(ValueError, match="sha256"):
        InnerModel(tmp_path)


def test_body_weights_are_the_nearest_vertex_s_with_k_1():
    body = load_body("neutral")
    pts = body.vertices[[10, 500, 3000]] + 0.01
    w = body_weights(pts, body, 1)
    from drape.geometry.queries import nearest_vertex_weights

    assert np.allclose(w, nearest_vertex_weights(pts, body.vertices, body.weights), atol=1e-6)
    assert np.allclose(body_weights(pts, body, 8).sum(1), 1, atol=1e-6)
