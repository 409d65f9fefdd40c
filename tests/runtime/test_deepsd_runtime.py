"""Batched posing (numpy + ORT) against a per-frame loop and an independent torch posing."""

import json
import shutil

import numpy as np
import pytest
import torch

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.export.deepsd import export_deepsd_from_checkpoints
from drape.runtime.deepsd import DeePSDModel, pose_outfit
from drape.training import physics


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("model")
    export_deepsd_from_checkpoints("unused", out, init=True)
    return out


def test_manifest_lists_files_and_io(model_dir):
    m = json.loads((model_dir / "manifest.json").read_text())
    assert m["trained"] is False and set(m["files"]) == {"outfit", "pose"}
    outs = {o["name"]: o for o in m["files"]["outfit"]["outputs"]}
    assert outs["weights"]["shape"] == [-1, 24] and outs["blend_shapes"]["shape"] == [128, -1, 3]
    assert m["files"]["pose"]["inputs"][0] == {"name": "poses", "shape": [-1, 72], "datatype": "FP32"}
    assert sum(f["bytes"] for f in m["files"].values()) <= 10 * 2**20


def test_tampered_file_is_refused(model_dir, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(model_dir, bad)
    blob = bytearray((bad / "pose.onnx").read_bytes())
    blob[-10] ^= 0xFF
    (bad / "pose.onnx").write_bytes(bytes(blob))
    with pytest.raises(ValueError, match="sha256"):
        DeePSDModel(bad)


def test_batched_posing_equals_loop_and_torch(model_dir):
    model = DeePSDModel(model_dir)
    body = load_body("neutral")
    o = generate_outfit("tshirt", vertices=1200, seed=2)
    rig = model.rig(o.vertices, o.faces, body)
    assert np.allclose(rig.weights.sum(1), 1.0, atol=1e-5)
    clip = load_clip("walk")
    poses, trans = clip.poses[:20].astype(np.float64), clip.trans[:20].astype(np.float64)
    keys = model.pose_keys(poses)
    batched = pose_outfit(o.vertices, rig, keys, body.joints, poses, trans)
    assert batched.shape == (20, len(o.vertices), 3) and batched.dtype == np.float32
    for t in (0, 7, 19):
        single = pose_outfit(o.vertices, rig, keys[t : t + 1], body.joints, poses[t : t + 1], trans[t : t + 1])
        assert np.abs(single[0] - batched[t]).max() < 1e-5
    # independent formulation: torch FK/LBS of the training code, offsets summed key by key
    offs = sum(keys[:, p, None, None] * rig.blend_shapes[p][None] for p in range(keys.shape[1]))
    tr = physics.skinning_transforms(torch.as_tensor(poses), torch.as_tensor(body.joints, dtype=torch.float64))
    ref = physics.lbs(torch.as_tensor(o.vertices + offs, dtype=torch.float64),
                      torch.as_tensor(rig.weights, dtype=torch.float64), tr).numpy() + trans[:, None]
    assert np.abs(ref - batched).max() < 1e-4


def test_the_speed_bench_runs_ort_on_the_mesh_torch_runs_on(model_dir):
    """bench.deepsd times ORT's rig against torch eager on `network_inputs(vertices, faces)`: the ORT model must
    read the same mesh (the service's default subdivides the 1k outfit's 25+ mm edges into ~3.9k vertices)."""
    from bench.deepsd import ort_model
    from drape.runtime.deepsd import network_inputs

    model = ort_model(model_dir)
    o = generate_outfit("tshirt,trousers", vertices=1000, seed=1000)
    session, seen = model.sessions["outfit"], []

    class Spy:
        def run(self, outputs, inputs):
            seen.append(len(inputs["features"]))
            return session.run(outputs, inputs)

    model.sessions["outfit"] = Spy()
    model.rig(o.vertices, o.faces)
    assert seen == [len(network_inputs(o.vertices, o.faces)["features"])] == [len(o.vertices)]
