"""The inner-layer network's rig refit out of the body (drape.training.layers_inner_fit): it takes cloth out
of the body at its fit poses with at most 4 influences, leaves the network alone, and `apply` keeps it only
where the validation split says so, once, with the manifest's sha256 and figures true to the files."""

import json
import shutil

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.geometry.mesh import vertex_normals
from drape.geometry.queries import MeshDistance
from drape.runtime.deepsd import pose_outfit
from drape.runtime.layers import INNER_MODELS, InnerModel
from drape.runtime.model_files import checked_files
from drape.training import layers_inner
from drape.training.layers_inner_fit import apply, fit_inner_rig, fit_poses


def _inside(vertices, rig, model, body, poses):
    posed = pose_outfit(vertices, rig, model.pose_keys(poses), body.joints, poses).astype(np.float64)
    shares = []
    for g, b in zip(posed, body.pose(poses).astype(np.float64), strict=True):
        shares.append(np.mean(MeshDistance(b, body.faces, vertex_normals(b, body.faces)).signed_distance(g) < 0))
    return float(np.mean(shares))


def _network_folder():
    """A shipped inner network whose folder holds the network's own rig (its fit not served)."""
    for folder in sorted(INNER_MODELS.iterdir()):
        m = folder / "manifest.json"
        if m.exists() and json.loads(m.read_text()).get("collision_fit", {"served": "network"})["served"] == "network":
            return folder
    pytest.skip("every shipped inner network serves a fitted rig")


def test_apply_keeps_the_better_rig_once_and_the_manifest_says_what_the_files_are(tmp_path):
    shipped = _network_folder()
    folder = tmp_path / shipped.name
    shutil.copytree(shipped, folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest.pop("collision_fit", None)  # as the training exports it
    manifest["config"].pop("collision_fit", None)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with np.load(shipped / "rig.npz") as z:
        network_shapes = z["blend_shapes"]
    pose_onnx = (folder / "pose.onnx").read_bytes()
    cfg = layers_inner.load_config(shipped.name)
    # a small fit and a small validation, so that the test runs in seconds
    cfg = {**cfg, "collision_fit": {"gain": 1.0, "stride": 24},
           "validation": {**cfg["validation"], "frames_per_clip": 3, "clips": cfg["validation"]["clips"][:1]}}
    record = apply(folder, cfg)
    written = json.loads((folder / "manifest.json").read_text())
    checked_files(folder, written, ("pose", "rig"))  # the sha256 are the files'
    assert (folder / "pose.onnx").read_bytes() == pose_onnx  # the network is untouched
    assert written["collision_fit"] == record and written["config"]["collision_fit"] == cfg["collision_fit"]
    better = record["validation_fitted"]["score"] < record["validation_network"]["score"]
    assert record["served"] == ("fitted" if better else "network")
    with np.load(folder / "rig.npz") as z:
        assert np.array_equal(z["blend_shapes"], network_shapes) != better
    with pytest.raises(ValueError, match="measured already"):
        apply(folder, cfg)


def test_the_fit_takes_cloth_out_of_the_body_at_its_poses_with_four_influences():
    model = InnerModel(_network_folder(), threads=1)  # the network's own rig
    body = load_body("neutral")
    poses = fit_poses(24)
    fitted = fit_inner_rig(model.vertices, model.faces, model.rig, model.pose_keys, body, poses, 1.0)
    assert np.count_nonzero(fitted.weights, axis=1).max() <= 4 < np.count_nonzero(model.rig.weights, axis=1).max()
    assert np.allclose(fitted.weights.sum(axis=1), 1.0, atol=1e-5)
    before, after = _inside(model.vertices, model.rig, model, body, poses), _inside(model.vertices, fitted, model,
                                                                                   body, poses)
    assert after < 0.95 * before, (before, after)  # gain 1: a least-squares fit takes back part of each push


def test_the_fit_poses_take_the_first_frames_of_the_real_clips_the_network_trained_on():
    from drape.training.deepsd_data import pose_pool
    from drape.training.layers_inner_fit import real_fit_motions

    cfg = layers_inner.load_config("tshirt")
    assert cfg["collision_fit"]["real_frames"] > 0  # the served t-shirt's fit reads them
    clip = cfg["mocap"]["train"][0]
    short = {**cfg, "mocap": {**cfg["mocap"], "train": [clip]}}
    real = real_fit_motions(short, 20)
    # the poses the training read: the clip's rows of its pose pool (the pool's last rows, after the embedded
    # clips; the pool zeroes the root's rotation)
    pool = pose_pool({**short, "procedural_motions": 0})
    assert len(real) == 1 and real[0].shape == (20, 24, 3)
    n = len(real_fit_motions(short, 10**6)[0])
    np.testing.assert_array_equal(real[0][:, 1:], pool[len(pool) - n:][:20, 1:])
    assert real_fit_motions(short, 0) == []
    base = fit_poses(24)
    poses = fit_poses(24, real)
    assert np.array_equal(poses[:len(base)], base) and np.array_equal(poses[len(base):], real[0][::24])
