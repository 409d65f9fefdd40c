"""`drape eval deepsd` machinery on a tiny held-out set with a freshly initialised export."""

import json

import numpy as np

from drape.export.deepsd import export_deepsd_from_checkpoints
from drape.training import deepsd_data
from drape.training.deepsd import load_config
from drape.training.deepsd_eval import METHODS, evaluate, format_table, write_results


def test_eval_rows_and_written_table(tmp_path, monkeypatch):
    monkeypatch.setattr(deepsd_data, "CACHE", tmp_path / "outfits")
    cfg = load_config()
    cfg.update(eval_outfits=["skirt", "tshirt,trousers"], eval_vertices=600, heldout_clips=["kick"],
               eval_frames_per_clip=2)
    config_path = tmp_path / "cfg.json"
    config_path.write_text(json.dumps(cfg))
    model = tmp_path / "model"
    export_deepsd_from_checkpoints("unused", model, init=True)
    results = evaluate(config_path, model, log=lambda *_: None)
    assert len(results["rows"]) == 2 * len(METHODS)
    for r in results["rows"]:
        assert 0.0 <= r["collision_triangle_pct"] <= 100.0 and r["edge_error_mm"] >= 0.0
    base = [r for r in results["rows"] if r["method"] == "baseline"]
    # every method yields finite metrics, the baseline included
    assert all(np.isfinite(r["bending"]) for r in base)
    table = format_table(results)
    assert "| skirt | model |" in table and "kick" in table
    manifest, doc = write_results(results, model, tmp_path / "eval.md")
    assert json.loads(manifest.read_text())["evaluation"]["rows"] == results["rows"]
    assert doc.read_text().startswith("# DeePSD evaluation")
