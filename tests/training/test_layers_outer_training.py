"""The outer-layer network's training pieces that need no dataset: the batches (pairs of consecutive frames for
the temporal loss) and the edge and step losses against independent formulations."""

import numpy as np
import torch

from drape.geometry.mesh import unique_edges
from drape.geometry.metrics import edge_lengths
from drape.training.layers_outer import (
    Sequence,
    edge_length_loss,
    follow_inner,
    sample_batch,
    step_loss,
)


def _sequence(frames: int, seed: int) -> Sequence:
    rng = np.random.default_rng(seed)
    t = 1000 * seed + np.arange(frames, dtype=np.float32)  # trans says which sequence and frame
    return Sequence(f"s{seed}", "proc", 0.008, rng.normal(size=(frames, 78)).astype(np.float32),
                    rng.normal(size=(frames, 24, 3)).astype(np.float32), t[:, None].repeat(3, 1),
                    rng.normal(size=(frames, 8)).astype(np.float32), rng.normal(size=(frames, 5, 3)).astype(np.float32),
                    t[:, None, None] + rng.normal(size=(frames, 7, 3)).astype(np.float32), [])


def test_pairs_are_consecutive_frames_of_the_window_and_carry_their_truth():
    seqs = [_sequence(40, 1), _sequence(55, 2)]
    batch = sample_batch(seqs, 30, 6, 10, np.random.default_rng(0), pairs=True)
    pick = batch["pick"].numpy()
    assert pick.shape == (6, 10) and (pick[:, 1::2] - pick[:, 0::2] == 1).all() and pick.max() < 30
    for b in range(6):  # trans says the sequence and the frame: the window's start + the picked frame
        seq, start = seqs[int(batch["trans"][b, 0, 0]) // 1000 - 1], int(batch["trans"][b, 0, 0]) % 1000 - pick[b, 0]
        assert np.array_equal(batch["trans"][b].numpy(), seq.trans[start + pick[b]])
        assert np.array_equal(batch["outer"][b].numpy(), seq.outer[start + pick[b]])
        assert np.array_equal(batch["features"][b].numpy(), seq.features[start:start + 30])
    single = sample_batch(seqs, 30, 6, 10, np.random.default_rng(0))
    assert (np.diff(single["pick"].numpy(), axis=1) > 0).all()  # distinct frames, sorted


def test_clip_batches_draw_thickness_in_the_range_and_carry_no_truth():
    clip = _sequence(50, 3)
    clip.outer = None  # a real clip nobody simulated
    batch = sample_batch([clip], 30, 64, 6, np.random.default_rng(1), thickness=(0.004, 0.012))
    h = batch["thickness"].numpy().ravel()
    assert "outer" not in batch and batch["inner"].shape == (64, 6, 5, 3)
    assert (h >= 0.004).all() and (h <= 0.012).all() and h.std() > 0.001  # drawn per window, not the clip's 8 mm
    mixed = sample_batch([clip, _sequence(40, 1)], 30, 8, 6, np.random.default_rng(2))
    assert "outer" not in mixed  # no truth for some windows: none is given


def test_follow_inner_moves_what_lies_on_the_inner_layer_and_not_what_hangs_free():
    rng = np.random.default_rng(4)
    sim_inner = rng.uniform(-0.1, 0.1, size=(3, 50, 3)).astype(np.float32) * [1, 1, 0]  # a sheet at z = 0
    served = sim_inner + np.array([0.0, 0.0, 0.02], np.float32)  # the served layer 2 cm further out
    outer = np.concatenate([sim_inner[:, :10] + [0, 0, 0.005], sim_inner[:, :10] + [0, 0, 0.02],
                            sim_inner[:, :10] + [0, 0, 0.5]], axis=1).astype(np.float32)
    moved = follow_inner(outer, sim_inner, served, 0.01, 0.03)
    step = (moved - outer)[..., 2]
    assert np.allclose(step[:, :10], 0.02) and np.allclose(step[:, 10:20], 0.01) and np.allclose(step[:, 20:], 0)
    assert np.allclose((moved - outer)[..., :2], 0)


def test_edge_length_loss_is_the_relative_edge_error_and_ignores_rigid_motion():
    rng = np.random.default_rng(3)
    faces = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4]])
    truth = rng.normal(size=(4, 5, 3))
    v = truth + 0.05 * rng.normal(size=truth.shape)
    e = unique_edges(faces)
    want = np.mean(((edge_lengths(v, e) - edge_lengths(truth, e)) / edge_lengths(truth, e)) ** 2)
    got = edge_length_loss(torch.as_tensor(v), torch.as_tensor(truth), torch.as_tensor(e))
    assert abs(float(got) - want) < 1e-9
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    moved = torch.as_tensor(truth @ q.T + [1.0, 2.0, 3.0])
    assert float(edge_length_loss(moved, torch.as_tensor(truth), torch.as_tensor(e))) < 1e-20


def test_step_loss_compares_the_steps_of_each_pair_only():
    rng = np.random.default_rng(4)
    truth = rng.normal(size=(6, 5, 3))  # three pairs
    shifted = truth + np.repeat(rng.normal(size=(3, 1, 3)), 2, axis=0)  # each pair moved as a whole
    assert float(step_loss(torch.as_tensor(shifted), torch.as_tensor(truth))) < 1e-20
    v = truth.copy()
    v[1] += [0.0, 0.003, 0.004]  # the first pair's second frame 5 mm off
    want = 0.005 ** 2 / 3
    assert abs(float(step_loss(torch.as_tensor(v), torch.as_tensor(truth))) - want) < 1e-12


def test_the_choice_bench_measures_deepsd_with_the_validation_clips_as_training_did(monkeypatch, tmp_path, capsys):
    """bench.layers_choice re-measures DeePSD's outer rig by training's rule (layers_outer.train: the validation
    clips and their caps' PENALTY included, as in the 'DeePSD then' score it prints beside). Here DeePSD's rig has
    the lower RMSE but is over the clip cap: the network stays served."""
    import json

    import bench.layers_choice as lc
    from drape.training import layers_outer

    (tmp_path / "deepsd").mkdir()
    (tmp_path / "deepsd" / "manifest.json").write_text(json.dumps({"version": "x"}))
    (tmp_path / "mgn_inner").mkdir()
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "manifest.json").write_text("{}")
    pair = tmp_path / "mgn_outer" / "tshirt_jacket"
    pair.mkdir(parents=True)
    pair.joinpath("manifest.json").write_text(json.dumps({
        "config": {"data": str(tmp_path / "data")}, "served": "mgn_outer", "validation": {"score": 70.0},
        "deepsd_validation": {"score": 1064.0}}))
    calls = []

    class Task:
        def __init__(self, cfg):
            self.cfg = cfg

        def sequences(self, split):
            return [f"{split} sequence"]

    def deepsd_validation(task, seqs, clips=None):
        calls.append(clips)
        return {"score": 64.0 + (layers_outer.PENALTY if clips else 0.0), "rmse_mm": 64.0, "l_coll_pct": 0.4,
                "sted": 0.1}

    monkeypatch.setattr(lc, "DEEPSD_DIR", tmp_path / "deepsd")
    monkeypatch.setattr(lc, "ASSETS", tmp_path)
    monkeypatch.setattr(layers_outer, "OuterTask", Task)
    monkeypatch.setattr(layers_outer, "validation_clips", lambda task: ["a real validation clip"])
    monkeypatch.setattr(layers_outer, "deepsd_validation", deepsd_validation)
    lc.main()
    assert calls == [["a real validation clip"]]
    assert "mgn_outer -> mgn_outer" in capsys.readouterr().out


def test_refined_targets_leave_the_body_and_keep_what_was_outside():
    from drape.assets.body import load_body
    from drape.assets.outfits import split_outfit
    from drape.geometry.queries import signed_distance_to_mesh
    from drape.training.layers_outer import refined_outer

    body = load_body("neutral")
    (inner, inner_faces), (outer, outer_faces) = split_outfit("tanktop,longsleeve", 4000, seed=7, body="neutral")
    rest = body.vertices.astype(np.float64)
    centre = rest.mean(0)
    sd = signed_distance_to_mesh(outer, rest, body.faces)
    near = np.argsort(sd)[:40]  # the sleeve's closest 40 vertices, 3 cm toward the body's centre: inside
    target = outer.astype(np.float32).copy()
    target[near] += (0.03 * (centre - outer[near]) / np.linalg.norm(centre - outer[near], axis=1)[:, None])
    before = signed_distance_to_mesh(target, rest, body.faces) < 0
    assert before.sum() >= 20

    def refined(x: np.ndarray) -> np.ndarray:
        return refined_outer((inner[None].astype(np.float32), inner_faces, x[None], outer_faces, rest[None],
                              body.faces, 0.006))

    (moved, figures), (undented, _) = refined(target), refined(outer.astype(np.float32))
    moved, undented = moved[0], undented[0]
    assert figures["in_body_before"] >= 20 and figures["in_body_after"] == 0 and figures["vertex_frames"] == len(outer)
    assert moved.shape == target.shape and moved.dtype == np.float32
    assert np.mean(signed_distance_to_mesh(moved, rest, body.faces) < 0) <= 0.001
    far = np.linalg.norm(outer[:, None] - outer[near][None], axis=-1).min(1) > 0.1  # 10 cm from every dent
    assert far.sum() > 1000 and np.abs(moved[far] - undented[far]).max() < 2e-3  # there: as without the dents


def test_the_repulsion_margin_is_each_frames_thickness_when_asked():
    """loss.margin_thickness: each posed frame's margin is its window's H_in (at least eps), in posed_batch's
    frame order (frame_thickness); without it, eps for all (the served networks learned to ignore H_in)."""
    from types import SimpleNamespace

    from drape.training.layers_outer import OuterTask, frame_thickness

    batch = {"thickness": torch.tensor([[0.002], [0.008]]), "pick": torch.zeros((2, 3), dtype=torch.int64)}
    h = frame_thickness(batch)
    assert np.allclose(h.numpy(), [0.002] * 3 + [0.008] * 3)
    sd = torch.full((6, 4), 0.005)  # every outer vertex 5 mm out of the inner layer
    fake = SimpleNamespace(repulsion_distance=lambda v, inner: (sd, torch.ones_like(sd, dtype=torch.bool)),
                           collider=SimpleNamespace(signed_distance=lambda v, t: torch.ones(v.shape[:2])))
    v, trans, transforms = torch.zeros((6, 4, 3)), torch.zeros((6, 3)), torch.zeros((6, 24, 3, 4))
    lw = {"eps": 0.003, "eps_body": 0.003, "body_frames": 2}
    fixed, _, _ = OuterTask.collision_terms(fake, v, None, trans, transforms, lw, h)
    assert float(fixed) == 0.0  # 5 mm clears a 3 mm margin
    ours, _, _ = OuterTask.collision_terms(fake, v, None, trans, transforms, {**lw, "margin_thickness": True}, h)
    # the 2 mm frames take eps (3 mm): clear; the 8 mm frames are 3 mm short, half the vertex-frames
    assert abs(float(ours) - 0.0015) < 1e-9
