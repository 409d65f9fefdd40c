"""Datasets: manifest and splits, the quality gate, resume, and the process pool / Ray paths."""

import json

import numpy as np
import pytest

from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.sim.dataset import build_dataset
from drape.sim.params import sample_params
from drape.sim.quality import LayerGate, QualityGate

FRAMES = 3


def _inputs():
    o = generate_outfit("skirt", vertices=220, seed=5, length=0.5)
    motions = [load_clip("walk"), load_clip("run")]
    return {"skirt": (o.vertices, o.faces)}, sample_params(2, seed=7), motions


def _build(out, **kw):
    garments, params, motions = _inputs()
    return build_dataset(out, garments, params, motions, FRAMES, holdout_params=1, holdout_motions=1,
                         progress=False, **kw)


def _arrays(d):
    out = {}
    for f in sorted((d / "items").glob("*.npz")):
        with np.load(f, allow_pickle=False) as z:
            out[f.name] = {k: z[k] for k in z.files}
    return out


def _same(a, b):
    assert a.keys() == b.keys() and a
    for name in a:
        for k in a[name]:
            assert np.array_equal(a[name][k], b[name][k]), (name, k)


def test_dataset_manifest_splits_and_resume(tmp_path):
    m = _build(tmp_path, workers=1)
    assert m["last_run"]["simulated"] == 4
    assert len(m["items"]) + len(m["rejected"]) == 4
    splits = {e["split"] for e in m["items"]}
    assert splits <= {"train", "test", "test_motions", "test_params"}
    s = m["splits"]
    assert not set(s["train_params"]) & set(s["test_params"])
    assert not set(s["train_motions"]) & set(s["test_motions"])
    for e in m["items"]:
        with np.load(tmp_path / e["file"], allow_pickle=False) as z:
            assert z["vertices"].shape[0] == FRAMES and z["vertices"].shape[2] == 3
            assert z["vertices"].dtype == np.float32 and z["poses"].shape == (FRAMES, 24, 3)
            assert json.loads(str(z["params"])) == m["params"][e["params"]]
            assert "penetration_p99_m" in json.loads(str(z["stats"]))
    assert json.loads((tmp_path / "manifest.json").read_text())["summary"]["items"] == len(m["items"])
    before = _arrays(tmp_path)
    # a finished dataset: no work
    assert _build(tmp_path, workers=1)["last_run"]["simulated"] == 0
    # a killed run (an item missing, a half-written temporary left behind) resumes with just that item
    victim = sorted((tmp_path / "items").glob("*.npz"))[0]
    victim.unlink()
    (tmp_path / "items" / (victim.name + ".tmp.npz")).write_bytes(b"partial")
    assert _build(tmp_path, workers=1)["last_run"]["simulated"] == 1
    _same(before, _arrays(tmp_path))


def test_failed_sequences_are_reported_and_excluded(tmp_path):
    m = _build(tmp_path, workers=1, gate=QualityGate(max_mean_strain=0.0))
    assert m["items"] == [] and len(m["rejected"]) == 4
    assert all(any("strain_mean" in why for why in r["reasons"]) for r in m["rejected"])
    assert not list((tmp_path / "items").glob("*.npz"))
    # each rejected sequence is kept beside its reasons, out of items/ (a use that tolerates the check may read it)
    for r in m["rejected"]:
        assert r["file"] == f"rejected/{r['key']}.npz" and {"params", "motion", "split"} <= set(r)
        with np.load(tmp_path / r["file"], allow_pickle=False) as z:
            assert np.isfinite(z["vertices"]).all() and z["vertices"].shape[0] == m["frames"]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_sequence_does_not_stop_the_others(tmp_path, workers):
    garments, params, motions = _inputs()
    v, f = garments["skirt"]
    bad = np.array(f, copy=True)
    bad[0, 0] = len(v)  # a face past the last vertex: its simulations raise
    kw = {"holdout_params": 1, "holdout_motions": 1, "progress": False}
    with pytest.raises(RuntimeError, match="broken__p00__walk"):
        build_dataset(tmp_path, {"skirt": (v, f), "broken": (v, bad)}, params, motions, FRAMES, workers=workers, **kw)
    # every other sequence was simulated and written; nothing of the failed ones
    m = json.loads((tmp_path / "manifest.json").read_text())
    done = [e["key"] for e in m["items"]] + [r["key"] for r in m["rejected"]]
    assert sorted(done) == sorted(f"skirt__p{p:02d}__{mo.name}" for p in range(2) for mo in motions)
    assert not list((tmp_path / "items").glob("broken*")) and not list((tmp_path / "rejected").glob("broken*"))
    # a rerun (the mesh mended) simulates just the failed ones
    m = build_dataset(tmp_path, {"skirt": (v, f), "broken": (v, f)}, params, motions, FRAMES, workers=1, **kw)
    assert m["last_run"]["simulated"] == 4 and len(m["items"]) + len(m["rejected"]) == 8


def test_resume_refuses_other_parameter_sets_or_frames(tmp_path):
    garments, params, motions = _inputs()
    kw = {"holdout_params": 1, "holdout_motions": 1, "progress": False, "workers": 1, "only_splits": ("test",)}
    build_dataset(tmp_path, garments, params, motions, FRAMES, **kw)
    # another seed (or --substeps, --thickness, ...): the finished item's cloth is not parameter set 1 any more
    with pytest.raises(ValueError, match="skirt__p01__run.npz was simulated with other parameters"):
        build_dataset(tmp_path, garments, sample_params(2, seed=8), motions, FRAMES, **kw)
    with pytest.raises(ValueError, match="other parameters or frames"):
        build_dataset(tmp_path, garments, params, motions, FRAMES - 1, **kw)
    # the same command resumes (nothing left to do)
    assert build_dataset(tmp_path, garments, params, motions, FRAMES, **kw)["last_run"]["simulated"] == 0


def test_process_pool_matches_serial(tmp_path):
    _build(tmp_path / "serial", workers=1)
    _build(tmp_path / "pool", workers=2)
    _same(_arrays(tmp_path / "serial"), _arrays(tmp_path / "pool"))


@pytest.mark.serial  # starts a Ray cluster
def test_ray_matches_local(tmp_path):
    ray = pytest.importorskip("ray")
    _build(tmp_path / "local", workers=1)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        _build(tmp_path / "ray", ray_address="auto")
    finally:
        ray.shutdown()
    _same(_arrays(tmp_path / "local"), _arrays(tmp_path / "ray"))


def test_only_splits_simulates_just_those_items(tmp_path):
    m = _build(tmp_path, workers=1, only_splits=("test",))
    assert m["last_run"]["simulated"] == 1  # 2 parameter sets x 2 motions, one held out of each
    assert [e["split"] for e in m["items"]] + [r.get("split", "test") for r in m["rejected"]] == ["test"]
    assert _build(tmp_path, workers=1, only_splits=("test",))["last_run"]["simulated"] == 0
    # another split into the same folder: the manifest keeps what earlier runs finished
    m = _build(tmp_path, workers=1, only_splits=("train",))
    assert m["last_run"]["simulated"] == 1
    assert sorted([e["split"] for e in m["items"]] + [r["split"] for r in m["rejected"]]) == ["test", "train"]


def test_only_params_simulates_just_those_sets(tmp_path):
    m = _build(tmp_path, workers=1, only_params=[1])
    assert m["last_run"]["simulated"] == 2  # parameter set 1 x 2 motions, every split
    assert {e["params"] for e in m["items"]} | {r["params"] for r in m["rejected"]} == {1}
    # the rest of the grid later, into the same folder
    assert _build(tmp_path, workers=1)["last_run"]["simulated"] == 2
    with pytest.raises(ValueError, match=r"only_params \[2\] are not among the 2 parameter sets"):
        _build(tmp_path, workers=1, only_params=[2])


def _layer_build(out, **kw):
    from drape.sim.layers import split_outfit
    from drape.sim.params import sample_layer_params

    (vi, fi), (vo, fo) = split_outfit("tshirt,jacket", 400, seed=1)
    params = sample_layer_params(3, seed=4, thickness=(0.004, 0.01), held_out=1)
    # a coarse 400-vertex outfit in two frames: the body limits are loosened (not what is tested here)
    kw.setdefault("gate", LayerGate(max_penetration_p99=0.05, max_penetration=0.1, max_mean_strain=0.5,
                                    max_strain_p99=2.0))
    return build_dataset(out, {"tshirt+jacket": (vi, fi, vo, fo)}, params, [load_clip("walk"), load_clip("run")],
                         2, holdout_params=1, holdout_motions=1, progress=False, workers=1, **kw)


@pytest.mark.slow  # about 17 s: `make test-slow`
def test_layer_dataset_items_splits_and_resume(tmp_path):
    m = _layer_build(tmp_path)
    assert m["layers"] and m["last_run"]["simulated"] == 6
    assert len(m["items"]) == 6 and not m["rejected"]
    assert set(m["gate"]) >= {"max_outer_in_inner_share", "max_outer_in_inner_p99"}
    # the held-out parameter set's thickness lies in a bin of its own, between training values
    h = [p["inner_thickness"] for p in m["params"]]
    assert m["splits"]["test_params"] == [2] and min(h[:2]) < h[2] < max(h[:2])
    for e in m["items"]:
        with np.load(tmp_path / e["file"], allow_pickle=False) as z:
            assert z["inner_vertices"].shape[::2] == (2, 3) and z["outer_vertices"].shape[::2] == (2, 3)
            assert z["inner_faces"].max() < z["inner_vertices"].shape[1]
            assert z["outer_faces"].max() < z["outer_vertices"].shape[1]
            assert float(z["inner_thickness"]) == pytest.approx(m["params"][e["params"]]["inner_thickness"])
            assert str(z["inner_garment"]) == "tshirt" and str(z["outer_garment"]) == "jacket"
            assert "outer_in_inner_share" in json.loads(str(z["stats"]))
    assert m["summary"]["outer_in_inner_share"]["max"] < 0.02
    before = _arrays(tmp_path)
    assert _layer_build(tmp_path)["last_run"]["simulated"] == 0
    victim = sorted((tmp_path / "items").glob("*.npz"))[0]
    victim.unlink()
    (tmp_path / "items" / (victim.name + ".tmp.npz")).write_bytes(b"partial")
    assert _layer_build(tmp_path)["last_run"]["simulated"] == 1
    _same(before, _arrays(tmp_path))



@pytest.mark.parametrize(("change", "said"), [
    ({"frames": 0}, "frames must be at least 1, got 0"),
    ({"holdout_motions": 2}, "holdout_motions must be in [1, 1], got 2"),
    ({"holdout_params": 0}, "holdout_params must be in [1, 1], got 0"),
])
def test_a_dataset_that_cannot_be_split_or_simulated_is_refused_before_its_folder_is_made(tmp_path, change, said):
    garments, params, motions = _inputs()
    kw = {"frames": FRAMES, "holdout_params": 1, "holdout_motions": 1, **change}
    with pytest.raises(ValueError, match=said.replace("[", r"\[").replace("]", r"\]")):
        build_dataset(tmp_path / "d", garments, params, motions, progress=False, **kw)
    assert not (tmp_path / "d").exists()
