"""The intrinsic-space networks: U-blocks blend their sub-layers, motion coefficients are non-negative
and unit norm, character space round-trips, training on a small synthetic dataset lowers the validation
errors, resumes, and the ONNX exports equal torch."""

import json
import shutil
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch

from drape.export.intrinsic import export_intrinsic
from drape.models.intrinsic import (
    IntrinsicConfig,
    IntrinsicSpace,
    UBlock,
    character_space,
    world_space,
)


def test_a_ublock_is_the_blend_of_its_sub_layers():
    torch.manual_seed(0)
    block = UBlock(5, 3, 4)
    x, c = torch.randn(7, 5), torch.rand(7, 4)
    W = block.linear.weight.reshape(4, 3, 5)
    b = block.linear.bias.reshape(4, 3)
    explicit = sum(c[:, k:k + 1] * (x @ W[k].T + b[k]) for k in range(4))
    assert torch.allclose(block(x, c), explicit, atol=1e-6)


def test_motion_coefficients_are_nonnegative_unit_vectors_and_spaces_round_trip():
    cfg = IntrinsicConfig(num_vertices=10, window=4)
    model = IntrinsicSpace(cfg, torch.zeros(10, 3))
    c = model.motion(torch.randn(6, 5, 24, 3))
    assert (c >= 0).all() and torch.allclose(c.norm(dim=1), torch.ones(6), atol=1e-5)
    q = torch.nn.functional.normalize(torch.randn(6, 4), dim=1)
    from drape.geometry.rotations import quaternion_to_matrix

    rot = torch.as_tensor(quaternion_to_matrix(q.numpy()), dtype=torch.float32)
    p, root = torch.randn(6, 10, 3), torch.randn(6, 3)
    cs = character_space(p, root, rot)
    assert torch.allclose(world_space(cs, root, rot), p, atol=1e-5)
    assert torch.allclose(cs[:, 0], (rot.transpose(1, 2) @ (p[:, 0] - root)[..., None])[..., 0], atol=1e-5)


def test_the_onnx_exports_equal_torch(tmp_path):
    torch.manual_seed(1)
    cfg = IntrinsicConfig(num_vertices=40, window=6, shape_widths=(32, 16), motion_widths=(32,),
                          invariant_widths=(16,))
    model = IntrinsicSpace(cfg, torch.randn(40, 3) * 0.1).eval()
    paths = export_intrinsic(model, tmp_path)
    v, w = torch.randn(9, 40, 3) * 0.1, torch.randn(9, 7, 24, 3) * 0.3
    with torch.no_grad():
        z = model.encode(v, w)
        out = model.decode(z, w)
    sess = {p.stem: ort.InferenceSession(str(p)) for p in paths if p.suffix == ".onnx"}
    s_ort = sess["shape_encode"].run(None, {"vertices": v.numpy()})[0]
    z_ort = sess["encode"].run(None, {"descriptor": s_ort, "windows": w.numpy()})[0]
    s2_ort = sess["decode"].run(None, {"latent": z_ort, "windows": w.numpy()})[0]
    out_ort = sess["shape_decode"].run(None, {"descriptor": s2_ort})[0]
    assert np.abs(z_ort - z.numpy()).max() <= 1e-4 and np.abs(out_ort - out.numpy()).max() <= 1e-4
    manifest = json.loads(paths[-1].read_text())
    assert manifest["files"]["encode"]["inputs"][0]["shape"][0] == -1  # dynamic frame count


@pytest.fixture(scope="module")
def synthetic_dataset(tmp_path_factory):
    """A garment that follows the body rigidly plus a per-parameter-set sag and a motion-driven swing:
    shapes depend on (parameter set, motion) as simulated ones do, in a learnable way."""
    from drape.assets.body import load_body
    from drape.assets.motion import load_clip
    from drape.geometry.character_space import character_space_numpy, root_frames
    from drape.sim.dataset import save_sequence, split_of, splits
    from drape.sim.params import sample_params

    out = tmp_path_factory.mktemp("intrinsic")
    (out / "items").mkdir()
    body = load_body("neutral")
    rng = np.random.default_rng(0)
    rest = rng.normal(scale=0.1, size=(60, 3)) + [0, 0.9, 0]
    faces = np.stack([np.arange(58), np.arange(1, 59), np.arange(2, 60)], 1).astype(np.int32)
    params = sample_params(6, seed=1)
    motions = ["walk", "dance_a", "kick"]
    s = splits(6, motions, 1, 1)
    items = []
    for i, p in enumerate(params):
        for m in motions:
            clip = load_clip(m)
            poses, trans = clip.poses[:40].astype(np.float64), clip.trans[:40].astype(np.float64)
            _, rp, rr = root_frames(poses, trans, body.joints, body.parents)
            sag = np.array([0, -0.05, 0]) * (i + 1) / 6
            swing = np.sin(np.arange(40) * 0.2)[:, None, None] * np.array([0.02 * (i % 3), 0, 0])
            local = rest[None] + sag + swing  # character space
            world = np.einsum("tnk,tjk->tnj", local, rr) + rp[:, None, :]
            assert np.allclose(character_space_numpy(world, rp, rr), local, atol=1e-9)
            key = f"g__p{i:02d}__{m}"
            save_sequence(out / "items" / f"{key}.npz", vertices=world, faces=faces, poses=poses, trans=trans,
                          fps=30.0, params=p, stats={}, garment="g", body="neutral", motion=m)
            items.append({"key": key, "file": f"items/{key}.npz", "garment": "g", "params": i, "motion": m,
                          "split": split_of(i, m, s), "stats": {}})
    (out / "manifest.json").write_text(json.dumps({"format": "drape-sim-dataset/1", "body": "neutral",
                                                   "items": items, "splits": s}))
    return out


def _tiny_config(dataset, width: int, steps: tuple[int, int], batch: int, every: int) -> dict:
    """A training config for the synthetic dataset: shape widths [width], the other widths width / 2,
    `steps` (shape, invariant), shape batch `batch`, `batch` / 2 frames per set, a checkpoint every `every`."""
    return {"template": "g", "dataset": str(dataset), "seed": 0,
            "model": {"window": 5, "descriptor": 8, "latent": 8, "coefficients": 4, "shape_widths": [width],
                      "motion_widths": [width // 2], "invariant_widths": [width // 2], "shape_scale": 10.0},
            "val_params": 1,
            "shape": {"steps": steps[0], "batch": batch, "lr": 0.003, "laplacian": 1.0},
            "invariant": {"steps": steps[1], "sets_per_batch": 3, "frames_per_set": batch // 2, "lr": 0.003,
                          "lambda": 10.0},
            "checkpoint_every": every}


def test_training_lowers_the_validation_errors_and_resumes(synthetic_dataset, tmp_path):
    from drape.training.intrinsic import train

    config = _tiny_config(synthetic_dataset, width=64, steps=(300, 300), batch=64, every=100)
    logs: list[str] = []
    model, summary = train(config, tmp_path / "ckpt", log=logs.append)
    first = [float(x.split("error ")[1].split(" mm")[0]) for x in logs if x.startswith("shape step")]
    assert summary["phases"]["shape"]["val_vertex_error_mm"] < 0.5 * first[0] or first[0] < 2.0, logs
    assert summary["phases"]["invariant"]["val_set_latent_error_mm"] < 20.0, logs
    again, summary2 = train(config, tmp_path / "ckpt", log=logs.append)  # resumes: nothing left to do
    assert summary2["phases"] == summary["phases"]
    assert summary2["seconds"] == summary["seconds"]  # the training's wall time, not the resumed export's


def test_the_invariant_phase_regularisers_are_seeded_and_change_the_run(synthetic_dataset, tmp_path):
    from drape.training.intrinsic import train

    config = _tiny_config(synthetic_dataset, width=32, steps=(50, 100), batch=32, every=50)
    reg = {**config, "invariant": {**config["invariant"], "weight_decay": 0.05, "window_noise": 0.01}}
    _, plain = train(config, tmp_path / "plain", log=lambda *_: None)
    _, a = train(reg, tmp_path / "a", log=lambda *_: None)
    _, b = train(reg, tmp_path / "b", log=lambda *_: None)
    err = [s["phases"]["invariant"]["val_set_latent_error_mm"] for s in (plain, a, b)]
    assert err[1] == err[2] and err[1] != err[0] and np.isfinite(err).all()
    assert plain["phases"]["shape"] == a["phases"]["shape"]  # the shape phase is untouched


def test_a_batch_of_one_set_or_more_sets_than_trained_on_fails_before_any_step(synthetic_dataset, tmp_path):
    from drape.training.intrinsic import train

    config = _tiny_config(synthetic_dataset, width=32, steps=(50, 50), batch=32, every=50)
    for sets in (1, 99):  # one set has no between-set variance (the loss's denominator): NaN, not a model
        config["invariant"]["sets_per_batch"] = sets
        with pytest.raises(ValueError, match=f"sets_per_batch is {sets} but must be in \\[2, "):
            train(config, tmp_path / "ckpt", log=lambda *_: None)
    assert not (tmp_path / "ckpt").exists() or not any((tmp_path / "ckpt").iterdir())


def test_validation_holds_out_the_last_parameter_sets_and_the_named_motions():
    from drape.training.intrinsic import split_validation
    from drape.training.intrinsic_data import Frames

    params, motions = np.meshgrid(np.arange(5), np.arange(3), indexing="ij")  # 5 sets x 3 motions, a frame each
    params, motions = params.ravel(), motions.ravel()
    n = len(params)
    frames = Frames(np.zeros((n, 4, 3), np.float32), np.zeros((n, 2, 24, 3), np.float32), params, motions,
                    np.zeros(n, int), ["a", "b", "c"])
    train, val = split_validation(frames, 2, ["b"])
    assert set(zip(train.params, train.motions, strict=True)) == {(p, m) for p in range(3) for m in (0, 2)}
    assert set(zip(val.params, val.motions, strict=True)) == ({(p, m) for p in (3, 4) for m in range(3)}
                                                 | {(p, 1) for p in range(5)})
    train, val = split_validation(frames, 1)
    assert set(val.params) == {4} and len(train) == 12
    with pytest.raises(ValueError, match="val_motions"):
        split_validation(frames, 1, ["walk"])
    with pytest.raises(ValueError, match="no training motion"):
        split_validation(frames, 1, ["a", "b", "c"])


def test_the_validation_bench_counts_the_frames_a_model_trained_on():
    from bench.intrinsic_validation import trained_on
    from drape.training.intrinsic import split_validation
    from drape.training.intrinsic_data import Frames

    params, motions = np.meshgrid(np.arange(5), np.arange(3), indexing="ij")
    params, motions = np.repeat(params.ravel(), 2), np.repeat(motions.ravel(), 2)  # two frames a sequence
    n = len(params)
    frames = Frames(np.zeros((n, 4, 3), np.float32), np.zeros((n, 2, 24, 3), np.float32), params, motions,
                    np.zeros(n, int), ["a", "b", "c"])
    _, val = split_validation(frames, 2, ["b"])
    assert trained_on(val, {"training": {"train_sequences": {"a": [0, 1, 2], "c": [0, 1, 2]}}}) == 0
    assert trained_on(val, {"training": {"train_sequences": {"a": [3], "b": [0, 4], "walk": [3]}}}) == 6
    assert trained_on(val, {}) is None


def _split_by_motion(dataset: Path, tmp_path: Path, **manifest: object) -> list[Path]:
    """The dataset's items copied into two folders, tmp_path/a (walk) and tmp_path/b (dance_a and kick, the test
    split's motion), each with the whole's manifest (updated by `manifest`) over its own items."""
    import shutil

    whole = {**json.loads((dataset / "manifest.json").read_text()), **manifest}
    folders = []
    for name, keep in (("a", {"walk"}), ("b", {"dance_a", "kick"})):
        d = tmp_path / name
        (d / "items").mkdir(parents=True)
        items = [it for it in whole["items"] if it["motion"] in keep]
        for it in items:
            shutil.copy(dataset / it["file"], d / it["file"])
        (d / "manifest.json").write_text(json.dumps({**whole, "items": items}))
        folders.append(d)
    return folders


def test_the_keyframe_bench_reads_the_validation_split_of_every_folder_a_config_trains_on(synthetic_dataset,
                                                                                          tmp_path):
    """bench.intrinsic_keyframes on a config with `extra_datasets` (its validation motion in the extra folder):
    the sequences of training's validation split, from both folders (it read `dataset` alone: a ValueError here,
    and only part of the split where the validation motion is in `dataset`)."""

    from bench.intrinsic_keyframes import validation_items
    from drape.training.intrinsic import split_validation, training_datasets
    from drape.training.intrinsic_data import load_frames

    folders = _split_by_motion(synthetic_dataset, tmp_path)
    for val_motions in (["dance_a"], ["walk"]):
        config = {"dataset": str(folders[0]), "extra_datasets": [str(folders[1])], "val_params": 1,
                  "val_motions": val_motions}
        frames, _, _ = load_frames(training_datasets(config), 5)
        _, val = split_validation(frames, 1, val_motions)
        expected = {(int(p), val.motion_names[m]) for p, m in zip(val.params, val.motions, strict=True)}
        got = validation_items(config, 5)
        assert {(it["params"], it["motion"]) for _, it in got} == expected and len(got) == len(expected)
        assert all((root / it["file"]).exists() for root, it in got)


def test_datasets_read_together_must_not_train_on_each_others_held_out_sets_or_motions(synthetic_dataset, tmp_path):
    """A second folder simulated with its own held-out motion (or --holdout-params) would put the first's test
    motion (or parameter set) into training: refused."""
    import shutil

    from drape.sim.dataset import split_of, splits
    from drape.training.intrinsic_data import load_frames

    whole = json.loads((synthetic_dataset / "manifest.json").read_text())
    for name, motions, holdout in (("motion", ["walk", "kick", "dance_a"], 1), ("params", ["walk", "dance_a", "kick"], 2)):
        d = tmp_path / name
        (d / "items").mkdir(parents=True)
        s = splits(6, motions, holdout, 1)
        items = [{**it, "split": split_of(it["params"], it["motion"], s)} for it in whole["items"]]
        for it in items:
            shutil.copy(synthetic_dataset / it["file"], d / it["file"])
        (d / "manifest.json").write_text(json.dumps({**whole, "items": items, "splits": s}))
        assert len(load_frames(d, 5)[0])  # alone, each is a valid dataset
        held = r"\[5\], test_motions \['dance_a', 'kick'\]" if name == "motion" else r"\[4, 5\], test_motions \['kick'\]"
        with pytest.raises(ValueError, match=f"holds out \\(test_params {held}\\)"):
            load_frames([synthetic_dataset, d], 5)


def test_several_datasets_read_as_their_union_and_must_share_the_parameter_sampler(synthetic_dataset, tmp_path):
    """A dataset split in two folders by motion (as more training motions are simulated into a folder of
    their own) loads the same frames as the whole; a folder sampled with other parameters is refused."""

    from drape.training.intrinsic_data import load_frames

    folders = _split_by_motion(synthetic_dataset, tmp_path, params=["the same sampler"])
    ref, faces_ref, _ = load_frames(synthetic_dataset, 5)
    got, faces, manifest = load_frames(folders, 5)
    assert got.motion_names == ref.motion_names and np.array_equal(faces, faces_ref)

    def rows(f):  # order-free comparison: (params, motion name, frame) -> vertices and windows
        return {(int(p), f.motion_names[m], int(t)): (v, w)
                for p, m, t, v, w in zip(f.params, f.motions, f.frame, f.vertices, f.windows, strict=True)}

    r, g = rows(ref), rows(got)
    assert r.keys() == g.keys() and len(g) == len(got)
    assert all(np.array_equal(r[k][0], g[k][0]) and np.array_equal(r[k][1], g[k][1]) for k in r)
    other = json.loads((folders[1] / "manifest.json").read_text())
    (folders[1] / "manifest.json").write_text(json.dumps({**other, "params": ["another sampler"]}))
    with pytest.raises(ValueError, match="'params' differs"):
        load_frames(folders, 5)


def test_a_run_killed_while_saving_a_checkpoint_resumes_to_the_run_it_would_have_been(synthetic_dataset, tmp_path,
                                                                                      monkeypatch):
    """A kill mid-save leaves no half-written checkpoint for the rerun to choke on, and a run resumed mid-phase
    draws the batches the uninterrupted run drew after that step (not the first steps' again)."""
    from drape.training.intrinsic import train

    config = _tiny_config(synthetic_dataset, width=32, steps=(100, 100), batch=32, every=25)
    _, fresh = train(config, tmp_path / "fresh", log=lambda *_: None)
    real_save = torch.save

    def killed_at(stem: str):
        def save(obj, f, *args, **kwargs):  # noqa: ANN001, ANN202
            if stem in str(f):
                with open(f, "wb") as fh:
                    fh.write(b"PK\x03\x04 half a checkpoint")
                raise KeyboardInterrupt
            return real_save(obj, f, *args, **kwargs)
        return save

    for stem in ("shape_75", "invariant_50"):  # killed in each phase, resumed from the checkpoint before
        monkeypatch.setattr(torch, "save", killed_at(stem))
        with pytest.raises(KeyboardInterrupt):
            train(config, tmp_path / "killed", log=lambda *_: None)
    monkeypatch.setattr(torch, "save", real_save)
    _, resumed = train(config, tmp_path / "killed", log=lambda *_: None)
    assert resumed["phases"] == fresh["phases"]


def test_a_rerun_on_other_training_or_validation_sequences_does_not_resume_the_old_checkpoints(synthetic_dataset,
                                                                                               tmp_path):
    """Checkpoints of a run on other sequences (a dataset that grew since, another validation split) would mix
    two trainings and keep a 'best' chosen on another split: the rerun refuses them, naming the sequences; and
    checkpoints of another config (here the validation split's) are refused as the other trainers refuse them."""
    from drape.training.intrinsic import train

    data = tmp_path / "data"
    shutil.copytree(synthetic_dataset, data)
    config = _tiny_config(data, width=32, steps=(30, 30), batch=32, every=30)
    train(config, tmp_path / "ckpt", log=lambda *_: None)
    with pytest.raises(ValueError, match=r"another config \(settings \['val_params'\] differ\)"):
        train({**config, "val_params": 2}, tmp_path / "ckpt", log=lambda *_: None)
    manifest = json.loads((data / "manifest.json").read_text())
    manifest["items"] = [i for i in manifest["items"] if i["key"] != "g__p00__walk"]  # a part-way dataset
    (data / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match=r"other sequences \(train: \[\] added, \['walk/0'\] gone\)"):
        train(config, tmp_path / "ckpt", log=lambda *_: None)
