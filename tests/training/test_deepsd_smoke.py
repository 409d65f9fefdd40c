"""The short smoke path: a few training steps on tiny outfits -> export -> ORT parity."""

import json

import numpy as np
import onnxruntime as ort
import pytest
import torch

from drape.export.deepsd import export_deepsd, started_from
from drape.models.deepsd import DeployedOutfitNet
from drape.runtime.deepsd import network_inputs
from drape.training import deepsd as deepsd_training
from drape.training import deepsd_data
from drape.training.deepsd import load_config, train


def test_train_export_parity(tmp_path, monkeypatch):
    monkeypatch.setattr(deepsd_data, "CACHE", tmp_path / "outfits")
    cfg = load_config()
    cfg.update(train_outfits=2, train_vertices=[300, 420], procedural_motions=1, procedural_frames=30,
               steps={"prior": 4, "physics": 4, "chi": 4}, checkpoint_every=4)
    net, pose, summary = train(cfg, tmp_path / "ckpt", log=lambda *_: None)
    assert set(summary["phases"]) == {"prior", "physics", "chi"}
    assert len(list((tmp_path / "ckpt").glob("step_*.pt"))) == 3
    assert summary["device"] == "cpu" and next(net.parameters()).device.type == "cpu"
    # checkpoints hold CPU tensors only and say where their steps ran (a GPU run's checkpoints load anywhere)
    state = torch.load(sorted((tmp_path / "ckpt").glob("step_*.pt"))[-1], weights_only=True)
    assert state["device"] == "cpu"
    assert all(t.device.type == "cpu" for t in state["outfit"].values())
    # a rerun resumes from the last checkpoint and does no more steps
    _, _, again = train(cfg, tmp_path / "ckpt", log=lambda *_: None)
    assert again["phases"] == {} and again["device"] == "cpu"
    # a rerun with another config does not resume (mix into, or take as its own) the first run's checkpoints
    with pytest.raises(ValueError, match="another config"):
        train({**cfg, "lr": cfg["lr"] * 2}, tmp_path / "ckpt", log=lambda *_: None)
    # nor a rerun of the same config whose pose pool changed meanwhile (an embedded clip added, a mocap file
    # replaced): the checkpoints record the data (training_data)
    real_pool = deepsd_training.pose_pool
    with monkeypatch.context() as m:
        m.setattr(deepsd_training, "pose_pool", lambda c: real_pool(c)[:-1])
        with pytest.raises(ValueError, match=r"other sequences \(pose_pool: \['\d+ poses sha256:"):
            train(cfg, tmp_path / "ckpt", log=lambda *_: None)
    assert json.loads(state["data"]) == deepsd_training.training_data(deepsd_data.train_specs(cfg), real_pool(cfg))
    paths = export_deepsd(net, pose, tmp_path / "onnx")
    spec = deepsd_data.train_specs(cfg)[0]
    v, f = deepsd_data.load_outfit(spec)
    inputs = network_inputs(v, f)
    w, d, _ = ort.InferenceSession(str(paths["outfit"])).run(None, inputs)
    with torch.no_grad():
        tw, td, _ = DeployedOutfitNet(net)(*(torch.from_numpy(inputs[k]) for k in ("features", "nbr_idx", "nbr_w")))
    assert np.abs(w - tw.numpy()).max() <= 1e-4 and np.abs(d - td.numpy()).max() <= 1e-4

    # a fine-tune config starts from that run's networks, not from random weights
    tune = dict(cfg, init_checkpoints=str(tmp_path / "ckpt"), steps={"prior": 0, "physics": 0, "chi": 0})
    tuned, tuned_pose, tuned_summary = train(tune, tmp_path / "tuned", log=lambda *_: None)
    assert tuned_summary["init_checkpoints"] == str(tmp_path / "ckpt")
    for a, b in ((net, tuned), (pose, tuned_pose)):
        for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
            assert torch.equal(x, y), name

    # the manifest of a fine-tune records the run it started from, followed back to the first run
    chain = started_from(tmp_path / "ckpt")
    assert len(chain) == 1 and chain[0]["steps_done"] == [4, 4, 4] and chain[0]["config"]["steps"] == cfg["steps"]
    assert started_from(tmp_path / "nowhere") == [{"checkpoints": str(tmp_path / "nowhere"), "missing": True}]


def test_phase_loss_override():
    from drape.training.deepsd import phase_loss_weights

    cfg = {"loss": {"edge": 6.0, "collision": 20.0}, "loss_phase": {"physics": {"edge": 8.0}}}
    assert phase_loss_weights(cfg, "physics") == {"edge": 8.0, "collision": 20.0}
    assert phase_loss_weights(cfg, "chi") == {"edge": 6.0, "collision": 20.0}
    assert phase_loss_weights({"loss": {"edge": 6.0}}, "physics") == {"edge": 6.0}
    with pytest.raises(ValueError, match="unknown phase 'phisics'"):
        phase_loss_weights({"loss": {"edge": 6.0}, "loss_phase": {"phisics": {"edge": 8.0}}}, "chi")
    with pytest.raises(ValueError, match="unknown loss weights"):
        phase_loss_weights({"loss": {"edge": 6.0}, "loss_phase": {"physics": {"edg": 8.0}}}, "physics")


def test_training_device_and_cpu_checkpoints():
    from drape.training.deepsd import _to_cpu, training_device

    assert training_device("cpu") == torch.device("cpu")
    assert training_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    nested = {"a": torch.ones(2), "b": [torch.zeros(1), 3], "c": {"d": (torch.ones(1),)}, "e": "text"}
    out = _to_cpu(nested)
    assert out["b"][1] == 3 and out["e"] == "text" and isinstance(out["c"]["d"], tuple)
    assert torch.equal(out["a"], nested["a"])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (the device machine)")
def test_step_loss_same_on_gpu(tmp_path, monkeypatch):
    """One physics step's loss and gradients agree between the CPU and the GPU (float32 tolerance)."""
    from drape.models.deepsd import OutfitNet, PoseNet
    from drape.training.deepsd import phase_loss_weights, step_loss

    monkeypatch.setattr(deepsd_data, "CACHE", tmp_path / "outfits")
    cfg = load_config()
    spec = deepsd_data.OutfitSpec("tshirt", 600, 1000, "neutral")
    torch.manual_seed(0)
    net, pose = OutfitNet(), PoseNet()
    poses = torch.randn(4, 24, 3, generator=torch.Generator().manual_seed(1)) * 0.3
    lw = phase_loss_weights(cfg, "physics")
    results = []
    for dev in ("cpu", "cuda"):
        outfit = deepsd_data.TrainOutfit(spec).to(dev)
        net.to(dev).zero_grad()
        pose.to(dev).zero_grad()
        loss, _ = step_loss("physics", outfit, poses.to(dev), net, pose, lw)
        loss.backward()
        results.append((float(loss), next(net.parameters()).grad.detach().cpu().clone()))
    (l_cpu, g_cpu), (l_gpu, g_gpu) = results
    assert abs(l_cpu - l_gpu) <= 1e-3 * abs(l_cpu) + 1e-5
    assert torch.allclose(g_cpu, g_gpu, rtol=1e-2, atol=1e-4)


def test_joint_candidates_train_export_and_serve_exactly(tmp_path, monkeypatch):
    """A model trained with `joint_candidates` keeps every vertex's weights on at most 4 joints of the body's
    skin near it, in training, in its ONNX export and in the runtime (which makes the mask from the body); the
    served 4-influence rig is then the network's own rig (pruning changes nothing)."""
    from drape.assets.body import load_body
    from drape.export.deepsd import write_manifest
    from drape.geometry.queries import candidate_joints
    from drape.models.deepsd import DeployedMaskedOutfitNet
    from drape.runtime.deepsd import DeePSDModel
    from drape.runtime.sparse_rig import fit_poses, sparse_rig

    monkeypatch.setattr(deepsd_data, "CACHE", tmp_path / "outfits")
    cfg = load_config()
    cfg.update(train_outfits=2, train_vertices=[300, 420], procedural_motions=1, procedural_frames=30,
               steps={"prior": 3, "physics": 3, "chi": 3}, checkpoint_every=3, joint_candidates={"influences": 4})
    net, pose, _ = train(cfg, tmp_path / "ckpt", log=lambda *_: None)
    spec = deepsd_data.train_specs(cfg)[0]
    outfit = deepsd_data.TrainOutfit(spec, cfg["joint_candidates"])
    assert outfit.joint_mask is not None and int(outfit.joint_mask.sum(1).max()) <= 4
    assert torch.allclose(outfit.prior_weights.sum(1), torch.ones(len(outfit.rest)))
    assert float((outfit.prior_weights * (1 - outfit.joint_mask)).abs().max()) == 0.0

    paths = export_deepsd(net, pose, tmp_path / "onnx", joint_mask=True)
    write_manifest(tmp_path / "onnx", version="test", config=cfg, evaluation=None, trained=True)
    v, f = deepsd_data.load_outfit(spec)
    body = load_body(spec.body)
    inputs = network_inputs(v, f)
    mask = candidate_joints(v, body.vertices, body.weights, influences=4).astype(np.float32)
    w, d, _ = ort.InferenceSession(str(paths["outfit"])).run(None, {**inputs, "joint_mask": mask})
    with torch.no_grad():
        tw, td, _ = DeployedMaskedOutfitNet(net)(*(torch.from_numpy(inputs[k]) for k in ("features", "nbr_idx", "nbr_w")),
                                                  torch.from_numpy(mask))
    assert np.abs(w - tw.numpy()).max() <= 1e-4 and np.abs(d - td.numpy()).max() <= 1e-4
    assert np.all(w[mask == 0] == 0) and np.allclose(w.sum(1), 1, atol=1e-5)

    model = DeePSDModel(tmp_path / "onnx")
    with pytest.raises(ValueError, match="needs the body"):
        model.rig(v, f)
    rig = model.rig(v, f, body)
    assert np.count_nonzero(rig.weights, axis=1).max() <= 4
    poses = fit_poses(40)
    served = sparse_rig(v, rig, body.joints, 4, poses, model.pose_keys(poses))
    assert np.abs(served.weights - rig.weights).max() <= 1e-6
    assert np.abs(served.blend_shapes - rig.blend_shapes).max() <= 1e-6
