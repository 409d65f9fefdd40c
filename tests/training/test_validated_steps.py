"""The layer networks' checkpoints (drape.training.validated_steps): a resumed run is the same run, and the step
kept is the lowest validation score, never a diverged (NaN) one."""

import math

import pytest
import torch

from drape.training.validated_steps import restore_best, resume, save_step


def _run(ckpt_dir, total: int, scores: dict[int, float] | None = None, cfg: dict | None = None,
         data: dict[str, list[str]] | None = None, log=lambda *_: None) -> torch.nn.Module:
    """The layer trainers' loop in miniature: seeded, built, resumed, stepped with dropout, measured every 2 steps."""
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(4, 16), torch.nn.Dropout(0.5), torch.nn.Linear(16, 1))
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    cfg = cfg or {"lr": 1e-2}
    done, elapsed, record = resume(ckpt_dir, model, opt, {"steps": {}}, log, cfg, data)
    x = torch.linspace(-1, 1, 32).reshape(8, 4)
    model.train()
    for step in range(done, total):
        loss = model(x).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        done = step + 1
        if done % 2 == 0:
            record["steps"][str(done)] = {"score": (scores or {}).get(done, float(loss))}
            save_step(ckpt_dir, model, opt, done, elapsed, record, cfg, data)
    return model


def test_a_resumed_run_draws_the_dropout_of_the_uninterrupted_one(tmp_path):
    whole = _run(tmp_path / "whole", 6)
    _run(tmp_path / "split", 2)
    resumed = _run(tmp_path / "split", 6)  # a rerun after an interruption
    for (name, a), b in zip(whole.state_dict().items(), resumed.state_dict().values(), strict=True):
        assert torch.equal(a, b), name


def test_a_diverged_step_is_never_the_best(tmp_path):
    model = _run(tmp_path, 6, scores={2: math.nan, 4: 1.0, 6: 2.0})
    kept = torch.load(tmp_path / "step_0000004.pt", weights_only=True)["model"]
    assert restore_best(tmp_path, model, {"steps": {"2": {"score": math.nan}, "4": {"score": 1.0},
                                                    "6": {"score": 2.0}}}) == "4"
    assert torch.load(tmp_path / "best.pt", weights_only=True)["step"] == 4
    for (name, a), b in zip(model.state_dict().items(), kept.values(), strict=True):
        assert torch.equal(a, b), name


def test_deepsd_candidates_skip_a_diverged_one():
    from drape.training.deepsd_validation import best_candidate

    cands = {"a": {"score": math.nan, "weights_off_prior_pct": 1.0}, "b": {"score": 3.0, "weights_off_prior_pct": 1.0}}
    assert best_candidate(cands) == "b"


def test_deepsd_candidates_all_diverged_choose_none_and_say_so():
    """Every candidate NaN: nothing to choose (choose_checkpoint then stops before `best.pt`), and the reason given
    is the divergence, not the weights limit."""
    from drape.training.deepsd_validation import best_candidate, no_candidate_reason

    cands = {"a": {"score": math.nan, "weights_off_prior_pct": 1.0}, "b": {"score": math.nan, "weights_off_prior_pct": 9.0}}
    assert best_candidate(cands) is None
    assert best_candidate(cands, 5.0) is None
    assert "every candidate diverged" in no_candidate_reason(cands, None)
    assert "every candidate diverged" in no_candidate_reason(cands, 5.0)
    assert "weights_off_prior_pct <= 0.5" in no_candidate_reason(cands, 0.5)


def test_a_rerun_with_another_config_does_not_resume_the_old_checkpoints(tmp_path):
    """`drape train mgn-outer --outer jacket --config <a variant>` defaults to the same folder as the plain config:
    resuming there would mix two trainings (or, finished, export the other config's network as this one's)."""
    _run(tmp_path, 2, cfg={"lr": 1e-2})
    with pytest.raises(ValueError, match="another config"):
        _run(tmp_path, 4, cfg={"lr": 1e-3})
    _run(tmp_path, 4, cfg={"lr": 1e-2})  # the same config resumes


def test_a_rerun_on_other_sequences_does_not_resume_the_old_checkpoints(tmp_path):
    """`make layers-data` added a validation sequence since the run was interrupted: resuming would validate the
    rest of the run on another split (and the steps before on the old one)."""
    data = {"train": ["a_p0_walk", "a_p1_walk"], "validation": ["b_p2_run"]}
    _run(tmp_path, 2, data=data)
    grown = {**data, "validation": ["b_p2_run", "b_p3_run"]}
    with pytest.raises(ValueError, match=r"other sequences \(validation: \['b_p3_run'\] added, \[\] gone\)") as err:
        _run(tmp_path, 4, data=grown)
    assert str(tmp_path) in str(err.value)
    with pytest.raises(ValueError, match=r"train: \[\] added, \['a_p1_walk'\] gone"):
        _run(tmp_path, 4, data={**data, "train": ["a_p0_walk"]})
    _run(tmp_path, 4, data=data)  # the same sequences resume


def test_an_older_checkpoint_without_sequences_resumes_with_a_line_in_the_log(tmp_path):
    _run(tmp_path, 2)  # saved before checkpoints recorded their sequences
    lines: list[str] = []
    _run(tmp_path, 4, data={"train": ["a"], "validation": ["b"]}, log=lines.append)
    assert any("does not record the sequences" in line for line in lines)
    with pytest.raises(ValueError, match="other sequences"):  # the steps saved since record them
        _run(tmp_path, 6, data={"train": ["a"], "validation": ["c"]})


def test_the_inner_trainer_records_the_embedded_clips_its_pose_pool_reads(monkeypatch):
    """The inner network's poses are the config's but for the embedded clips: a clip added there changes the pool."""
    from drape.training import layers_inner

    cfg = layers_inner.load_config("tshirt")
    clips = layers_inner.pool_clips(cfg)["train_embedded_clips"]
    assert clips and not set(clips) & set(cfg["heldout_clips"])
    monkeypatch.setattr(layers_inner, "list_clips", lambda: sorted([*clips, *cfg["heldout_clips"], "zz_new"]))
    assert layers_inner.pool_clips(cfg)["train_embedded_clips"] == [*clips, "zz_new"]
