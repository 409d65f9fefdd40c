"""The served rig: at most 4 (or 8) influences a vertex, blend shapes refit toward the dense rig; fit only
on clips DeePSD trained on."""

import json
from pathlib import Path

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import list_clips, load_clip
from drape.assets.outfits import generate_outfit
from drape.runtime.deepsd import DeePSDModel, Rig, pose_outfit
from drape.runtime.sparse_rig import FIT_CLIPS, _inverse3, fit_poses, sparse_rig, top_weights

CONFIG = Path(__file__).resolve().parents[2] / "drape" / "training" / "configs" / "deepsd.json"


def test_the_fit_clips_are_the_training_clips_not_the_held_out_ones():
    held = set(json.loads(CONFIG.read_text())["heldout_clips"])
    assert set(FIT_CLIPS) == set(list_clips()) - held
    assert fit_poses().shape == (300, 24, 3)


def test_top_weights_keep_k_and_sum_to_one():
    w = np.random.default_rng(0).dirichlet(np.ones(24), size=100)
    for k in (4, 8):
        t = top_weights(w, k)
        assert ((t > 0).sum(1) <= k).all() and np.allclose(t.sum(1), 1, atol=1e-6)
        assert np.array_equal(np.argmax(t, 1), np.argmax(w, 1))


def test_inverse3_equals_numpy():
    m = np.random.default_rng(1).normal(size=(50, 3, 3)) + 3 * np.eye(3)
    assert np.allclose(_inverse3(m), np.linalg.inv(m), atol=1e-10)


@pytest.fixture(scope="module")
def shipped():
    """The shipped model's blend shapes with dense weights (each vertex's skin weights averaged over its 200
    nearest body vertices: 5-9 joints a vertex), a rig that 4 or 8 influences cannot play as it is: the shipped
    model's own weights already keep to 4 joints (drape.geometry.queries.candidate_joints)."""
    from scipy.spatial import cKDTree

    model = DeePSDModel()
    body = load_body("neutral")
    o = generate_outfit("longsleeve,shorts", vertices=2500, seed=4)
    rig = model.rig(o.vertices, o.faces, body)
    _, near = cKDTree(body.vertices).query(o.vertices, k=200)
    weights = body.weights[near].mean(axis=1).astype(np.float32)
    assert np.median((weights > 1e-3).sum(1)) > 4
    return model, o, Rig(weights / weights.sum(1, keepdims=True), rig.blend_shapes)


@pytest.mark.parametrize("k", [4, 8])
def test_refit_brings_the_sparse_rig_closer_to_the_dense_one_on_held_out_clips(shipped, k):
    model, o, dense = shipped
    body = load_body("neutral")
    poses = fit_poses()
    served = sparse_rig(o.vertices, dense, body.joints, k, poses, model.pose_keys(poses))
    assert ((served.weights > 0).sum(1) <= k).all()
    plain = Rig(top_weights(dense.weights, k), dense.blend_shapes)
    for clip in ("walk", "dance_b"):  # held out of DeePSD's training and of the fit
        m = load_clip(clip)
        keys = model.pose_keys(m.poses)
        ref = pose_outfit(o.vertices, dense, keys, body.joints, m.poses, m.trans)
        err = {name: np.linalg.norm(pose_outfit(o.vertices, r, keys, body.joints, m.poses, m.trans) - ref,
                                    axis=2).mean()
               for name, r in (("served", served), ("plain", plain))}
        assert err["served"] < 0.8 * err["plain"], (clip, err)


def test_the_shipped_model_s_rig_is_served_as_it_is():
    """The shipped DeePSD keeps every vertex on at most 4 joints: the served 4-influence rig is its own rig."""
    model = DeePSDModel()
    assert model.joint_candidates is not None and model.joint_candidates["influences"] == 4
    body = load_body("female")
    o = generate_outfit("jacket", vertices=2000, seed=6, body="female")
    rig = model.rig(o.vertices, o.faces, body)
    assert np.count_nonzero(rig.weights, axis=1).max() <= 4
    poses = fit_poses()
    served = sparse_rig(o.vertices, rig, body.joints, 4, poses, model.pose_keys(poses))
    np.testing.assert_array_equal(served.weights > 0, rig.weights > 0)
    assert np.abs(served.weights - rig.weights).max() <= 1e-6
    assert np.abs(served.blend_shapes - rig.blend_shapes).max() <= 1e-6
