"""Choosing a DeePSD run's checkpoint on a validation split, never on the table `drape eval deepsd` reports.

The split (a config's `validation`): the evaluation's outfit types with other seeds (`outfit_seed` + i, on
the config's bodies in turn), posed along motions no training or evaluation uses: procedural motions of
`procedural_seeds`, legs-apart ones (`procedural_spread`: {"seeds", "spread"}, if any) and real CMU clips (`clips`, imported from the config's mocap folder onto each body at its
fps). Each candidate checkpoint is exported to ONNX and measured as it would be served (the
`influences`-influence rig of drape.runtime.sparse_rig, collision-fit by drape.runtime.collision_fit): the share of vertices inside the posed body (exact
closest-triangle signed distance; %) on `frames_per_clip` frames of each motion, and the mean edge-length
error against the template (mm). Score: inside % + edge error mm (1% inside weighs as 1 mm of edge error);
the lowest wins. The shipped model and the nearest-body-weights baseline are measured in the same run, for
comparison only. Runs on numpy + ONNX Runtime (torch only to load and export checkpoints).
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import numpy as np

from drape.assets.body import Body, load_body
from drape.assets.motion import Motion, import_motion
from drape.assets.procedural import generate_motion
from drape.geometry.lbs import pose_mesh
from drape.geometry.mesh import vertex_normals
from drape.geometry.metrics import edge_length_error_mm
from drape.geometry.queries import MeshDistance, nearest_vertex_weights
from drape.runtime.collision_fit import served_fit_frames, served_rig
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, pose_outfit
from drape.training.deepsd_data import OutfitSpec, load_outfit


def validation_specs(cfg: dict) -> list[OutfitSpec]:
    """The validation outfits: `eval_outfits` on the validation seeds, then, if `validation.oversize`
    ({"types", "looseness"}) is set, those types made oversize (seeds outfit_seed + 100 on)."""
    v, bodies = cfg["validation"], cfg["bodies"]
    specs = [OutfitSpec(t, cfg["eval_vertices"], v["outfit_seed"] + i, bodies[i % len(bodies)])
             for i, t in enumerate(cfg["eval_outfits"])]
    over: dict = v.get("oversize") or {}
    specs += [OutfitSpec(t, cfg["eval_vertices"], v["outfit_seed"] + 100 + i, bodies[i % len(bodies)],
                         float(over["looseness"]))
              for i, t in enumerate(over.get("types", []))]
    return specs


@lru_cache(maxsize=64)
def _clip(directory: str, name: str, body: str, fps: float) -> Motion:
    return import_motion((Path(directory) / f"{name}.bvh").read_bytes(), load_body(body), fps=fps, name=name).motion


def validation_motions(cfg: dict, body: str) -> list[Motion]:
    """The validation motions on `body`: procedural ones, legs-apart ones, then the real clips."""
    v = cfg["validation"]
    out = [generate_motion(v["procedural_frames"], seed=s, body=body) for s in v["procedural_seeds"]]
    wide: dict = v.get("procedural_spread") or {}
    out += [generate_motion(v["procedural_frames"], seed=s, body=body, spread=float(wide["spread"]))
            for s in wide.get("seeds", [])]
    mocap = cfg["mocap"]
    return out + [_clip(str(mocap["dir"]), c, body, float(mocap["fps"])) for c in v["clips"]]


Poser = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (poses (T, 24, 3), trans (T, 3)) -> (T, N, 3)


def measure_poser(cfg: dict, vertices: np.ndarray, faces: np.ndarray, body_name: str, body: Body,
                  pose: Poser) -> dict:
    """One garment (vertices (N, 3) m, faces) posed by `pose` along the validation motions on `body_name`
    (`frames_per_clip` frames each): {"inside_triangle_pct": share of vertices inside the posed body (exact
    closest triangle, %, mean over frames), "edge_error_mm": mean over motions}."""
    inside, edge = [], []
    for motion in validation_motions(cfg, body_name):
        frames = np.linspace(0, motion.num_frames - 1, cfg["validation"]["frames_per_clip"]).round().astype(int)
        poses, trans = motion.poses[frames].astype(np.float64), motion.trans[frames].astype(np.float64)
        posed = pose(poses, trans)
        for g, b in zip(posed, body.pose(poses, trans), strict=True):
            b = b.astype(np.float64)
            dist = MeshDistance(b, body.faces, vertex_normals(b, body.faces))
            inside.append(float(np.mean(dist.signed_distance(g.astype(np.float64)) < 0)))
        edge.append(edge_length_error_mm(posed, vertices, faces))
    return {"inside_triangle_pct": 100 * float(np.mean(inside)), "edge_error_mm": float(np.mean(edge))}


def _measure(cfg: dict, rig: Callable[[np.ndarray, np.ndarray, Body], Poser], log: Callable[[str], object]) -> dict:
    """Every validation outfit rigged by `rig(vertices, faces, body)`, posed along the validation motions."""
    per_outfit = {}
    for spec in validation_specs(cfg):
        verts, faces = load_outfit(spec)
        body = load_body(spec.body)
        per_outfit[spec.key] = measure_poser(cfg, verts, faces, spec.body, body, rig(verts, faces, body))
    record = summarise(list(per_outfit.values()))
    log(f"validation: {record['inside_triangle_pct']:.2f}% inside, {record['edge_error_mm']:.2f} mm edge error")
    return {**record, "outfits": per_outfit}


def summarise(rows: list[dict]) -> dict:
    """`measure_poser` results of several outfits -> {"score": inside % + edge mm, "inside_triangle_pct",
    "edge_error_mm"}: the means over outfits, scored as the checkpoint choice scores them."""
    inside_pct = float(np.mean([r["inside_triangle_pct"] for r in rows]))
    edge_mm = float(np.mean([r["edge_error_mm"] for r in rows]))
    return {"score": inside_pct + edge_mm, "inside_triangle_pct": inside_pct, "edge_error_mm": edge_mm}


def weights_off_prior(weights: np.ndarray, prior: np.ndarray) -> float:
    """Share (%) of vertices whose largest blend weight is on a joint that is not among the two largest of the
    nearest body vertex's weights. weights, prior: (N, 24). A sleeve skinned to the collar instead of the arm
    (its blend shapes then carry it along with the arm) scores high here while inside % and edge error stay
    low: DeePSD runs trained from scratch for 16,700-29,100 steps did that to 15-25% of a sleeved top."""
    top2 = np.argsort(-prior, axis=1)[:, :2]
    return 100 * float(np.mean(~(weights.argmax(axis=1)[:, None] == top2).any(axis=1)))


def validate(cfg: dict, model_dir: str | Path, log: Callable[[str], object] = print) -> dict:
    """The model in `model_dir`, as served (its sparse, collision-fit rig), on the validation split: {"score",
    "inside_triangle_pct", "edge_error_mm", "outfits": {key: {...}}}."""
    model = DeePSDModel(model_dir)
    fit, collision = served_fit_frames(model.pose_keys)
    influences = cfg["validation"]["influences"]

    off_prior: list[float] = []  # per validation outfit, in _measure's order (validation_specs)

    def rig(verts: np.ndarray, faces: np.ndarray, body: Body) -> Poser:
        dense = model.rig(verts, faces, body)
        off_prior.append(weights_off_prior(dense.weights, nearest_vertex_weights(verts, body.vertices, body.weights)))
        r = served_rig(verts, dense, body, influences, fit, collision, faces)
        return lambda poses, trans: pose_outfit(verts, r, model.pose_keys(poses), body.joints, poses, trans)

    record = _measure(cfg, rig, log)
    off = dict(zip(record["outfits"], off_prior, strict=True))
    for key, share in off.items():
        record["outfits"][key]["weights_off_prior_pct"] = share
    record["weights_off_prior_pct"] = float(np.mean(list(off.values())))
    record["weights_off_prior_worst_pct"] = max(off.values())
    log(f"weights off the body's nearest two joints: {record['weights_off_prior_pct']:.1f}% of vertices "
        f"(worst outfit {record['weights_off_prior_worst_pct']:.1f}%)")
    return record


def validate_baseline(cfg: dict, log: Callable[[str], object] = print) -> dict:
    """What a user would otherwise do, on the validation split: LBS with the nearest body vertex's weights."""
    def rig(verts: np.ndarray, faces: np.ndarray, body: Body) -> Poser:
        w = nearest_vertex_weights(verts, body.vertices, body.weights)
        return lambda poses, trans: pose_mesh(verts, w, body.joints, poses, trans)

    return _measure(cfg, rig, log)


def best_candidate(candidates: dict[str, dict], max_weights_off_prior_pct: float | None = None) -> str | None:
    """The lowest-score candidate among those whose weights_off_prior_pct is at most the limit (every candidate
    when the limit is None) and whose score is not NaN (a diverged network); None when none qualifies
    (no_candidate_reason says why)."""
    eligible = {k: c["score"] for k, c in candidates.items()
                if (max_weights_off_prior_pct is None or c["weights_off_prior_pct"] <= max_weights_off_prior_pct)
                and not math.isnan(c["score"])}
    return min(eligible, key=lambda k: eligible[k]) if eligible else None


def no_candidate_reason(candidates: dict[str, dict], max_weights_off_prior_pct: float | None) -> str:
    """Why best_candidate chose none: every candidate within the weights limit diverged (NaN score), or none is
    within the limit."""
    within = [k for k, c in candidates.items()
              if max_weights_off_prior_pct is None or c["weights_off_prior_pct"] <= max_weights_off_prior_pct]
    if within:
        among = ("" if max_weights_off_prior_pct is None
                 else f" among those with weights_off_prior_pct <= {max_weights_off_prior_pct}")
        return f"every candidate diverged (NaN validation score){among}: {sorted(within)}"
    return (f"no candidate has its weights on the body's joints (weights_off_prior_pct <= {max_weights_off_prior_pct}: "
            f"{ {k: round(c['weights_off_prior_pct'], 1) for k, c in candidates.items()} })")


def choose_checkpoint(cfg: dict, ckpt_dir: str | Path, log: Callable[[str], object] = print) -> dict:
    """Validate the checkpoints at the config's `validation.steps` (summed steps of every phase), copy the
    best to `ckpt_dir/best.pt` (what `drape export deepsd` exports when present) and write every figure to
    `ckpt_dir/validation.json`. Returns that record. With `validation.max_weights_off_prior_pct` in the config,
    only candidates whose weights stay on the body's joints that far qualify (`best_candidate`); a diverged one (NaN
    score) never does. When none qualifies, ValueError saying why after the record is written (so
    `make deepsd-model` stops before it exports)."""
    import torch

    from drape.export.deepsd import export_deepsd, write_manifest
    from drape.models.deepsd import OutfitNet, PoseNet

    ckpt_dir = Path(ckpt_dir)
    record: dict = {"rule": "lowest inside % + edge error mm, served rig, validation split", "candidates": {}}
    for step in cfg["validation"]["steps"]:
        path = ckpt_dir / f"step_{int(step):07d}.pt"
        if not path.exists():
            raise FileNotFoundError(f"validation.steps names {step}, but {path} does not exist (checkpoints are "
                                    f"saved every checkpoint_every steps of a phase and at each phase's end)")
        state = torch.load(path, weights_only=True)
        outfit, pose = OutfitNet(), PoseNet()
        outfit.load_state_dict(state["outfit"])
        pose.load_state_dict(state["pose"])
        with tempfile.TemporaryDirectory() as tmp:
            candidates = cfg.get("joint_candidates")
            export_deepsd(outfit, pose, tmp, joint_mask=candidates is not None)
            write_manifest(tmp, version="candidate", config={"joint_candidates": candidates} if candidates else {},
                           evaluation=None, trained=True)
            log(f"{path.name}:")
            record["candidates"][path.name] = validate(cfg, tmp, log)
    log("the shipped model, for comparison:")
    shipped = json.loads((MODEL_DIR / "manifest.json").read_text())["version"]
    record["shipped"] = {"version": shipped, **validate(cfg, MODEL_DIR, log)}
    log("the nearest-body-weights baseline:")
    record["baseline"] = validate_baseline(cfg, log)
    limit = cfg["validation"].get("max_weights_off_prior_pct")
    best = best_candidate(record["candidates"], limit)
    record["chosen"] = best
    if limit is not None:
        record["rule"] += f", among candidates with weights_off_prior_pct <= {limit}"
    (ckpt_dir / "validation.json").write_text(json.dumps(record, indent=2) + "\n")
    if best is None:
        (ckpt_dir / "best.pt").unlink(missing_ok=True)
        raise ValueError(f"{no_candidate_reason(record['candidates'], limit)}; nothing to export "
                         f"({ckpt_dir / 'validation.json'} has every figure)")
    shutil.copyfile(ckpt_dir / best, ckpt_dir / "best.pt")
    log(f"chosen on validation: {best}")
    return record
