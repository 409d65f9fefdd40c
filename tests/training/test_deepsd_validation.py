"""A DeePSD run with real mocap in its pose pool and its checkpoint chosen on the validation split: a few
steps on tiny outfits, two candidate checkpoints, the lower validation score wins and is what export takes."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from drape.assets.body import load_body
from drape.export.deepsd import export_deepsd_from_checkpoints
from drape.training import deepsd_data
from drape.training.deepsd import load_config, train
from drape.training.deepsd_validation import choose_checkpoint, validation_specs

MOCAP = Path("..") / "shared" / "data" / "mocap"
pytestmark = pytest.mark.skipif(not (MOCAP / "05_01_walk.bvh").exists(), reason="needs ../shared/data/mocap")


@pytest.fixture
def cfg(tmp_path, monkeypatch):
    monkeypatch.setattr(deepsd_data, "CACHE", tmp_path / "outfits")
    c = load_config(Path("drape/training/configs/deepsd_wide.json"))
    c.update(train_outfits=2, train_vertices=[300, 420], procedural_motions=1, procedural_frames=30,
             steps={"prior": 4, "physics": 4, "chi": 4}, checkpoint_every=4, eval_outfits=["tshirt"],
             eval_vertices=300, mocap={**c["mocap"], "train": ["05_01_walk"]},
             validation={**c["validation"], "clips": ["06_01_walk"], "procedural_seeds": [7001],
                         "procedural_frames": 30, "frames_per_clip": 2, "steps": [8, 12]})
    return c


def test_real_mocap_widens_the_pose_pool(cfg):
    without = deepsd_data.pose_pool({**cfg, "mocap": None})
    pool = deepsd_data.pose_pool(cfg)
    walk = deepsd_data.mocap_poses(MOCAP, "05_01_walk", 30.0)
    assert len(pool) == len(without) + len(walk) and np.allclose(pool[len(without):, 1:], walk[:, 1:])
    assert not {s.seed for s in validation_specs(cfg)} & {s.seed for s in deepsd_data.train_specs(cfg)}
    assert not set(cfg["validation"]["clips"]) & set(load_config(Path(
        "drape/training/configs/deepsd_wide.json"))["mocap"]["train"])


def test_legs_apart_motions_join_the_pose_pool_and_the_validation_motions(cfg):
    from drape.assets.procedural import generate_motion
    from drape.training.deepsd_validation import validation_motions

    without = deepsd_data.pose_pool(cfg)
    pool = deepsd_data.pose_pool({**cfg, "procedural_spread": {"motions": 2, "spread": 1.0}})
    wide = generate_motion(cfg["procedural_frames"], seed=cfg["seed"] + 901, spread=1.0).poses
    assert len(pool) == len(without) + 2 * len(wide)
    start = cfg["procedural_motions"] * cfg["procedural_frames"] + len(wide)  # after the plain ones, 2nd wide
    assert np.allclose(pool[start:start + len(wide), 1:], wide[:, 1:])
    v = {**cfg["validation"], "procedural_spread": {"seeds": [7101], "spread": 1.0}}
    motions = validation_motions({**cfg, "validation": v}, "neutral")
    assert len(motions) == len(validation_motions(cfg, "neutral")) + 1
    assert np.array_equal(motions[1].poses, generate_motion(30, seed=7101, body="neutral", spread=1.0).poses)
    assert not {7101} & set(cfg["validation"]["procedural_seeds"])


def test_oversize_outfits_join_training_and_validation_on_their_own_seeds(cfg):
    from scipy.spatial import cKDTree

    plain_train, plain_val = deepsd_data.train_specs(cfg), validation_specs(cfg)
    over = {**cfg, "train_oversize": {"outfits": 3, "types": ["tshirt", "tanktop"], "looseness": [1.5, 3.0]},
            "validation": {**cfg["validation"], "oversize": {"types": ["longsleeve"], "looseness": 2.0}}}
    train_specs, val_specs = deepsd_data.train_specs(over), validation_specs(over)
    assert train_specs[:len(plain_train)] == plain_train and val_specs[:len(plain_val)] == plain_val
    added, val_added = train_specs[len(plain_train):], val_specs[len(plain_val):]
    assert [s.types for s in added] == ["tshirt", "tanktop", "tshirt"] and [s.seed for s in added] == [5000, 5001, 5002]
    assert all(1.5 <= s.looseness <= 3.0 for s in added) and [s.looseness for s in val_added] == [2.0]
    assert not {s.seed for s in val_specs} & {s.seed for s in train_specs}
    assert len({s.key for s in train_specs + val_specs}) == len(train_specs) + len(val_specs)
    # an oversize garment hangs off the body: farther from it than the same type drawn in [0, 1]
    spec = added[0]
    v, f = deepsd_data.load_outfit(spec)
    v0, _ = deepsd_data.load_outfit(deepsd_data.OutfitSpec(spec.types, spec.vertices, spec.seed, spec.body, 0.5))
    body = cKDTree(load_body(spec.body).vertices)  # distance to the nearest body vertex, metres
    assert np.median(body.query(v)[0]) > 0.045 > np.median(body.query(v0)[0])


def test_the_pose_pool_repairs_the_real_clips_rotation_flips_when_asked(cfg):
    flipped = {**cfg, "mocap": {**cfg["mocap"], "train": ["05_10_dance"]}}
    kept = deepsd_data.pose_pool(flipped)
    repaired = deepsd_data.pose_pool({**flipped, "mocap": {**flipped["mocap"], "flips": "repair"}})
    assert kept.shape == repaired.shape and not np.allclose(kept, repaired)
    assert np.array_equal(kept, deepsd_data.pose_pool({**flipped, "mocap": {**flipped["mocap"], "flips": "keep"}}))
    with pytest.raises(ValueError, match="mocap.flips"):
        deepsd_data.pose_pool({**flipped, "mocap": {**flipped["mocap"], "flips": "yes"}})


@pytest.mark.slow  # about 25 s: `make test-slow`
def test_the_checkpoint_is_chosen_on_validation_and_exported(cfg, tmp_path):
    train(cfg, tmp_path / "ckpt", log=lambda *_: None)
    # a few steps from random weights put most vertices on joints far from the body's: the weights limit
    # refuses every candidate, keeps the record and leaves nothing to export
    strict = {**cfg, "validation": {**cfg["validation"], "max_weights_off_prior_pct": 8.0}}
    with pytest.raises(ValueError, match="no candidate has its weights on the body's joints"):
        choose_checkpoint(strict, tmp_path / "ckpt", log=lambda *_: None)
    refused = json.loads((tmp_path / "ckpt" / "validation.json").read_text())
    assert refused["chosen"] is None and not (tmp_path / "ckpt" / "best.pt").exists()
    assert all(c["weights_off_prior_pct"] > 8.0 for c in refused["candidates"].values())

    cfg = {**cfg, "validation": {k: v for k, v in cfg["validation"].items() if k != "max_weights_off_prior_pct"}}
    record = choose_checkpoint(cfg, tmp_path / "ckpt", log=lambda *_: None)
    scores = {k: v["score"] for k, v in record["candidates"].items()}
    assert set(scores) == {"step_0000008.pt", "step_0000012.pt"}
    assert record["chosen"] == min(scores, key=scores.get)
    assert {"shipped", "baseline"} <= set(record) and record["baseline"]["score"] > 0
    chosen = torch.load(tmp_path / "ckpt" / record["chosen"], weights_only=True)
    best = torch.load(tmp_path / "ckpt" / "best.pt", weights_only=True)
    assert all(torch.equal(a, b) for a, b in zip(chosen["outfit"].values(), best["outfit"].values(), strict=True))
    export_deepsd_from_checkpoints(tmp_path / "ckpt", tmp_path / "model")
    manifest = json.loads((tmp_path / "model" / "manifest.json").read_text())
    taken = manifest["training"]["config"]["_checkpoint"]
    assert taken["file"] == "best.pt" and taken["validation"]["chosen"] == record["chosen"]
    assert taken["steps_done"] == chosen["done"].tolist()


def test_weights_off_prior_counts_vertices_skinned_away_from_their_body_joints():
    from drape.training.deepsd_validation import weights_off_prior

    rng = np.random.default_rng(0)
    prior = rng.dirichlet(np.ones(24) * 0.3, size=50)
    assert weights_off_prior(prior, prior) == 0.0
    second = np.zeros_like(prior)
    second[np.arange(50), np.argsort(-prior, axis=1)[:, 1]] = 1.0  # the prior's second joint still counts as on
    assert weights_off_prior(second, prior) == 0.0
    away = np.zeros_like(prior)
    away[np.arange(50), np.argsort(-prior, axis=1)[:, -1]] = 1.0  # the prior's weakest joint: off
    assert weights_off_prior(away, prior) == 100.0
    mixed = np.concatenate([prior[:40], away[40:]])
    assert weights_off_prior(mixed, prior) == 20.0


def test_best_candidate_keeps_to_the_weights_limit():
    from drape.training.deepsd_validation import best_candidate

    cands = {"a": {"score": 2.0, "weights_off_prior_pct": 12.0}, "b": {"score": 3.0, "weights_off_prior_pct": 5.0},
             "c": {"score": 3.5, "weights_off_prior_pct": 4.0}}
    assert best_candidate(cands) == "a"
    assert best_candidate(cands, 8.0) == "b"
    assert best_candidate(cands, 4.5) == "c"
    assert best_candidate(cands, 1.0) is None


def test_posture_motions_join_the_pose_pool_after_the_procedural_ones(cfg):
    from drape.assets.procedural import generate_motion
    from drape.geometry.skeleton import JOINT_NAMES

    without = deepsd_data.pose_pool(cfg)
    pool = deepsd_data.pose_pool({**cfg, "procedural_posture": {"motions": 2, "posture": 1.0}})
    frames = cfg["procedural_frames"]
    upright = generate_motion(frames, seed=cfg["seed"] + deepsd_data.POSTURE_SEED_OFFSET + 1).poses
    bent = generate_motion(frames, seed=cfg["seed"] + deepsd_data.POSTURE_SEED_OFFSET + 1, posture=1.0).poses
    assert len(pool) == len(without) + 2 * frames
    start = cfg["procedural_motions"] * frames + frames  # after the plain ones, the 2nd posture motion
    assert np.allclose(pool[start:start + frames, 1:], bent[:, 1:])
    assert np.array_equal(pool[start + frames:], without[cfg["procedural_motions"] * frames:])  # the rest as before
    collars = [JOINT_NAMES.index(n) for n in ("left_collar", "right_collar", "spine3")]
    assert np.abs(bent[:, collars] - upright[:, collars]).max() > 0.1  # the posture is what the motions add
