"""The committed training configs against the settings each trainer reads (drape.training.config_file.SETTINGS)."""

import json
import re

import pytest

from drape.training.config_file import CONFIGS, SETTINGS, check_settings, read_config


def _kind(name: str) -> str:
    return next(k for k in sorted(SETTINGS, key=len, reverse=True) if name == k or name.startswith(f"{k}_"))


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.json")), ids=lambda p: p.stem)
def test_every_committed_config_holds_only_settings_its_trainer_reads(path):
    read_config(path, _kind(path.stem))


def test_each_setting_of_the_schema_is_used_by_some_committed_config():
    """No dead names in SETTINGS: each one (and each name one level down, where SETTINGS lists them) appears in a
    committed config of its kind, so the schema is what the configs are, not a list that drifted. Names one level
    down taken from what the object is passed to (a model's config dataclass) may be more than the configs use."""
    seen: dict[str, dict[str, set]] = {k: {} for k in SETTINGS}
    for path in CONFIGS.glob("*.json"):
        for name, value in json.loads(path.read_text()).items():
            seen[_kind(path.stem)].setdefault(name, set()).update(value if isinstance(value, dict) else ())
    for kind, schema in SETTINGS.items():
        assert set(schema) == set(seen[kind]), kind
        for name, inner in schema.items():
            if callable(inner):
                assert seen[kind][name] <= set(inner()), (kind, name)
            elif inner is not None:
                assert set(inner) == seen[kind][name], (kind, name)


def test_model_and_candidate_settings_are_what_their_dataclass_or_function_takes():
    """`model` is a model config dataclass's keywords and `joint_candidates` candidate_joints': any of theirs is
    taken (basis_init was refused: no committed config set it), what the trainer sets itself is not."""
    check_settings({"model": {"basis_init": "rig", "width": 64}}, "mgn_inner", "c.json")
    check_settings({"joint_candidates": {"influences": 4, "stride": 2, "margin": 0.02}}, "deepsd", "c.json")
    for kind, settings, said in (("mgn_outer", {"model": {"num_vertices": 3}}, "model: unknown setting 'num_vertices'"),
                                 ("deepsd", {"joint_candidates": {"parents": [0]}}, "unknown setting 'parents'"),
                                 ("intrinsic", {"model": {"latnet": 8}}, "(did you mean 'latent'?)")):
        with pytest.raises(ValueError, match=re.escape(said)):
            check_settings(settings, kind, "c.json")


def test_a_setting_one_level_down_is_checked_only_where_the_schema_lists_names():
    """loss_phase maps phases to weights, checked by the DeePSD trainer itself: any phase name passes here."""
    check_settings({"loss_phase": {"anything": {}}}, "deepsd", "c.json")
    with pytest.raises(ValueError, match=r"^c.json: steps: unknown setting 'anything'; steps holds chi, physics, prior$"):
        check_settings({"steps": {"anything": 1}}, "deepsd", "c.json")
