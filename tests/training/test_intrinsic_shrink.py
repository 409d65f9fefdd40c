"""Keyframe latents pulled toward the training mean: the shrink factors against an independent formulation (the
factor that minimises the squared error of a set's mean guessed from one frame, on draws with known variances), and
the served encoder applying the manifest's factors."""

import json
import shutil

import numpy as np
import pytest

from drape.runtime.intrinsic import IntrinsicGarment
from drape.training.intrinsic_shrink import shrink_factors
from tests.intrinsic_model import intrinsic_model


def test_shrink_factors_are_the_least_squares_guess_of_a_set_s_mean_from_one_frame():
    rng = np.random.default_rng(3)
    Z, sets, frames = 6, 400, 300
    between = np.array([1.0, 0.5, 0.1, 2.0, 0.01, 1.0])
    within = np.array([1.0, 2.0, 0.1, 0.5, 1.0, 0.0001])
    means = rng.normal(0.0, np.sqrt(between), (sets, Z))
    latents = means[:, None] + rng.normal(0.0, np.sqrt(within), (sets, frames, Z))
    s, w = shrink_factors(between, list(latents))
    assert np.allclose(w, within, rtol=0.03)
    assert np.allclose(s, between / (between + within), rtol=0.03)
    # independently: the factor a minimising mean((a z - mu)^2) over every frame (training mean 0) by least squares
    a = (latents * means[:, None]).sum(axis=(0, 1)) / (latents**2).sum(axis=(0, 1))
    assert np.allclose(s, a, atol=0.02)
    # and it beats the encoder's latent alone (a = 1) and the mean alone (a = 0) on every dimension
    err = {k: ((k * latents - means[:, None]) ** 2).mean(axis=(0, 1)) for k in (0.0, 1.0)}
    mine = ((s * latents - means[:, None]) ** 2).mean(axis=(0, 1))
    assert np.all(mine <= err[0.0] + 1e-9) and np.all(mine <= err[1.0] + 1e-9)
    with pytest.raises(ValueError, match="no parameter set"):
        shrink_factors(between, [])


def test_the_encoder_pulls_keyframe_latents_by_the_manifest_s_factors(tmp_path):
    tg = intrinsic_model()
    raw = IntrinsicGarment(tg.path)
    assert np.all(raw.keyframe_shrink == 1)  # a manifest without the field keeps the encoder's latents
    shutil.copytree(tg.path, tmp_path / "m")
    path = tmp_path / "m" / "manifest.json"
    manifest = json.loads(path.read_text())
    factors = np.linspace(0.0, 1.0, raw.latent_size)
    path.write_text(json.dumps(manifest | {"keyframe_shrink": factors.tolist()}))
    pulled = IntrinsicGarment(tmp_path / "m")
    poses = np.zeros((12, 24, 3))
    poses[:, 16, 2] = np.linspace(0.0, 0.8, 12)
    trans = np.zeros((12, 3))
    shape = raw.decode(np.tile(raw.latent_mean.astype(np.float32), (12, 1)) + 0.3, poses, trans)[9]
    z_raw, z = raw.encode(shape, poses, trans, 9), pulled.encode(shape, poses, trans, 9)
    assert np.allclose(z, raw.latent_mean + factors * (z_raw - raw.latent_mean), atol=1e-6)
    assert abs(z[0] - raw.latent_mean[0]) < 1e-6 and abs(z[-1] - z_raw[-1]) < 1e-6
    # every frame's latents (the invariance statistics) stay the encoder's own
    seq = raw.decode(np.tile(z_raw, (12, 1)), poses, trans)
    assert np.array_equal(pulled.encode_frames(seq, poses, trans), raw.encode_frames(seq, poses, trans))
    for bad in (factors[:-1], factors + 0.5):
        path.write_text(json.dumps(manifest | {"keyframe_shrink": bad.tolist()}))
        with pytest.raises(ValueError, match="keyframe_shrink"):
            IntrinsicGarment(tmp_path / "m")


def test_calibrate_writes_the_factors_of_the_config_s_validation_sets_into_the_manifest(tmp_path):
    """`drape train intrinsic`'s last step on a model folder: the factors from the last `val_params` training sets'
    sequences (every motion), an extra dataset folder not simulated here skipped, the source and version recorded."""
    from drape.assets.motion import load_clip
    from drape.export.intrinsic import VERSION
    from drape.sim.dataset import save_sequence, split_of, splits
    from drape.sim.params import sample_params
    from drape.training.intrinsic_shrink import calibrate

    tg = intrinsic_model()
    shutil.copytree(tg.path, tmp_path / "model")
    g = IntrinsicGarment(tmp_path / "model")
    data = tmp_path / "data"
    (data / "items").mkdir(parents=True)
    motions, params = ["walk", "dance_a", "kick"], sample_params(4, seed=1)
    s = splits(4, motions, 1, 1)  # training sets 0..2, motions walk, dance_a
    rng = np.random.default_rng(0)
    items = []
    for i, p in enumerate(params):
        z = g.latent_mean + g.latent_std * rng.standard_normal(g.latent_size)
        for m in motions:
            clip = load_clip(m)
            poses, trans = clip.poses[:20].astype(np.float64), clip.trans[:20].astype(np.float64)
            world = g.decode(np.tile(z, (20, 1)).astype(np.float32), poses, trans)
            key = f"{tg.path.name}__p{i:02d}__{m}"
            save_sequence(data / "items" / f"{key}.npz", vertices=world, faces=g.faces, poses=poses, trans=trans,
                          fps=30.0, params=p, stats={}, garment=tg.path.name, body="neutral", motion=m)
            items.append({"key": key, "file": f"items/{key}.npz", "params": i, "motion": m,
                          "split": split_of(i, m, s)})
    (data / "manifest.json").write_text(json.dumps({"items": items, "splits": s}))
    path = tmp_path / "model" / "manifest.json"
    path.write_text(json.dumps(json.loads(path.read_text()) | {"version": "0.0.1"}))  # an earlier version
    config = {"dataset": str(data), "extra_datasets": [str(tmp_path / "not simulated")], "val_params": 2}
    # no training record in the manifest (this model was not trained): training's rule, the last 2 sets present
    fields = calibrate(tmp_path / "model", config, log=lambda _: None)
    source = fields["keyframe_shrink_source"]
    assert source["parameter_sets"] == [1, 2] and source["sequences"] == 4 and source["datasets"] == [str(data)]
    per_set = []
    for i in (1, 2):
        seqs = [np.load(data / "items" / f"{tg.path.name}__p{i:02d}__{m}.npz") for m in ("walk", "dance_a")]
        per_set.append(np.concatenate([g.encode_frames(q["vertices"], q["poses"], q["trans"]) for q in seqs]))
    expected, _ = shrink_factors(g.latent_std**2, per_set)
    assert np.allclose(fields["keyframe_shrink"], expected, atol=1e-6)
    again = IntrinsicGarment(tmp_path / "model")
    assert again.version == VERSION and np.allclose(again.keyframe_shrink, expected, atol=1e-6)
    # with the training record, the sets it held out whole (in val_sequences, in no train_sequences), whatever
    # val_params says; a config other than the one it was trained with is refused
    record = {"config": {"dataset": str(data), "val_params": 2},
              "train_sequences": {"walk": [0, 1], "dance_a": [0]}, "val_sequences": {"walk": [2], "dance_a": [1, 2]}}
    path.write_text(json.dumps(json.loads(path.read_text()) | {"training": record}))
    assert calibrate(tmp_path / "model", config, log=lambda _: None)["keyframe_shrink_source"]["parameter_sets"] == [2]
    with pytest.raises(ValueError, match="trained with val_params 2, the config given has 1"):
        calibrate(tmp_path / "model", config | {"val_params": 1}, log=lambda _: None)


def test_the_cli_calibrates_an_exported_model_without_training(tmp_path, monkeypatch):
    from drape import cli

    called = []
    monkeypatch.setattr("drape.training.intrinsic_shrink.calibrate", lambda out, config: called.append((out, config)))
    monkeypatch.setattr("drape.training.intrinsic.train", lambda *a, **k: pytest.fail("--calibrate-only trained"))
    cli.main(["train", "intrinsic", "--template", "skirt", "--calibrate-only", "--out", str(tmp_path)])
    assert called and str(called[0][0]) == str(tmp_path) and called[0][1]["template"] == "skirt"
