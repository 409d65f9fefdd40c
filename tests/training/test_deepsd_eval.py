"""`drape eval deepsd` machinery on a tiny held-out set with a freshly initialised export."""

import json
from pathlib import Path

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.export.deepsd import export_deepsd_from_checkpoints
from drape.geometry.lbs import pose_mesh
from drape.geometry.mesh_io import load_mesh, save_mesh
from drape.geometry.queries import nearest_vertex_weights
from drape.training import deepsd_data
from drape.training.deepsd import load_config
from drape.training.deepsd_eval import (
    METHODS,
    REAL_CLIPS,
    UNSEEN_BODY_OUTFITS,
    evaluate,
    format_table,
    write_results,
)


def eval_setup(tmp_path, monkeypatch, outfits, vertices, frames):
    """A small evaluation config (held-out clip kick) and a freshly initialised export -> (config path, model)."""
    monkeypatch.setattr(deepsd_data, "CACHE", tmp_path / "outfits")
    cfg = load_config()
    cfg.update(eval_outfits=outfits, eval_vertices=vertices, heldout_clips=["kick"], eval_frames_per_clip=frames)
    config_path = tmp_path / "cfg.json"
    config_path.write_text(json.dumps(cfg))
    model = tmp_path / "model"
    export_deepsd_from_checkpoints("unused", model, init=True)
    return config_path, model


def test_eval_rows_and_written_table(tmp_path, monkeypatch):
    config_path, model = eval_setup(tmp_path, monkeypatch, ["skirt", "tshirt,trousers"], 600, 2)
    results = evaluate(config_path, model, log=lambda *_: None, ground_truth=None, real_mocap=None)
    assert "ground_truth" not in results and "mean_real" not in results
    assert len(results["rows"]) == (2 + len(UNSEEN_BODY_OUTFITS)) * len(METHODS)
    assert {r["body"] for r in results["rows"] if r["set"] == "unseen_body"} == {"heavy"}
    for r in results["rows"]:
        assert 0.0 <= r["collision_triangle_pct"] <= 100.0 and r["edge_error_mm"] >= 0.0
        # one share per clip (kick alone here), whose mean over equal frame counts is the row's
        assert len(r["clip_triangle_pct"]) == 1
        assert np.mean(r["clip_triangle_pct"]) == pytest.approx(r["collision_triangle_pct"])
    base = [r for r in results["rows"] if r["method"] == "baseline"]
    # every method yields finite metrics, the baseline included
    assert all(np.isfinite(r["bending"]) for r in base)
    table = format_table(results)
    assert "| skirt | model |" in table and "kick" in table
    worst = max(r["clip_triangle_pct"][0] for r in results["rows"] if r["method"] == "served" and r["set"] == "deepmimic")
    assert f"served {worst:.2f}%" in table.split("Worst single clip")[1]
    manifest, doc = write_results(results, model, tmp_path / "eval.md")
    assert json.loads(manifest.read_text())["evaluation"]["rows"] == results["rows"]
    assert doc.read_text().startswith("# DeePSD evaluation")


def fake_sim_dataset(root):
    """A `drape sim dataset`-shaped directory whose 'simulated' kick sequence is the baseline's posing."""
    o = generate_outfit("skirt", vertices=600, seed=5)
    save_mesh(root / "skirt.obj", o.vertices, o.faces)
    verts, faces = load_mesh(root / "skirt.obj")
    body = load_body("neutral")
    items = []
    for clip in ("kick", "dance_a"):  # dance_a is not a held-out clip: ignored
        m = load_clip(clip)
        poses, trans = m.poses[:4], m.trans[:4]
        truth = pose_mesh(verts, nearest_vertex_weights(verts, body.vertices, body.weights), body.joints,
                          poses.astype(np.float64), trans.astype(np.float64)).astype(np.float32)
        (root / "items").mkdir(exist_ok=True)
        np.savez(root / "items" / f"skirt__{clip}.npz", vertices=truth, faces=faces, poses=poses, trans=trans)
        items.append({"file": f"items/skirt__{clip}.npz", "garment": "skirt", "motion": clip})
    (root / "manifest.json").write_text(json.dumps({"body": "neutral", "items": items}))


def test_ground_truth_error_against_simulated_sequences(tmp_path, monkeypatch):
    config_path, model = eval_setup(tmp_path, monkeypatch, ["skirt"], 400, 1)
    fake_sim_dataset(tmp_path / "sim")
    gt = evaluate(config_path, model, log=lambda *_: None, ground_truth=tmp_path / "sim",
                  real_mocap=None)["ground_truth"]
    assert [r["clip"] for r in gt["rows"]] == ["kick"] and gt["rows"][0]["sequences"] == 1
    row = gt["rows"][0]
    assert row["baseline"] < 1e-2  # the 'simulation' is the baseline itself
    assert row["model"] > 1.0  # an untrained model's weights and blend shapes are not the baseline's
    assert "| kick | 1 |" in format_table({"rows": [], "mean": {}, "ground_truth": gt,
                                           "settings": {"heldout_clips": ["kick"], "frames_per_clip": 1,
                                                        "outfits": []}})


REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "mocap"


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/mocap (real CMU clips) is not beside the repository")
def test_real_cmu_clips_make_a_second_table(tmp_path, monkeypatch):
    config_path, model = eval_setup(tmp_path, monkeypatch, ["skirt"], 400, 2)
    results = evaluate(config_path, model, log=lambda *_: None, ground_truth=None, real_mocap=REAL, external=None)
    groups = [r["set"] for r in results["rows"]]
    assert groups.count("deepmimic") == groups.count("cmu") == len(METHODS)
    # without a folder of external garments, no fitted set
    assert "mean_fitted" not in results and "fitted_cmu" not in groups
    assert results["settings"]["real_clips"] == list(REAL_CLIPS)
    assert set(results["mean_real"]) == set(METHODS)
    assert "real CMU mocap" in format_table(results)


EXTERNAL = REAL.parent / "external"


@pytest.mark.skipif(not (REAL.is_dir() and EXTERNAL.is_dir()), reason="../shared/data (real CMU clips, external "
                    "garments) is not beside the repository")
def test_external_garments_are_fitted_and_measured_on_the_real_clips(tmp_path, monkeypatch):
    config_path, model = eval_setup(tmp_path, monkeypatch, ["skirt"], 400, 1)
    external = tmp_path / "external"
    external.mkdir()
    garment = sorted(EXTERNAL.glob("*.obj"))[0]
    (external / garment.name).write_bytes(garment.read_bytes())
    results = evaluate(config_path, model, log=lambda *_: None, ground_truth=None, real_mocap=REAL, external=external)
    fitted = [r for r in results["rows"] if r["set"] == "fitted_cmu"]
    assert [r["method"] for r in fitted] == list(METHODS)
    assert {r["outfit"] for r in fitted} == {garment.stem} and {r["body"] for r in fitted} == {"neutral"}
    # the fitted mesh keeps the file's vertices (fitting moves them, it adds none)
    assert fitted[0]["vertices"] == len(load_mesh(garment)[0])
    assert all(len(r["clip_triangle_pct"]) == len(REAL_CLIPS) for r in fitted)
    assert results["settings"]["fitted_garments"] == [garment.stem] and set(results["mean_fitted"]) == set(METHODS)
    assert f"({garment.stem}), fitted onto `neutral`" in format_table(results)
