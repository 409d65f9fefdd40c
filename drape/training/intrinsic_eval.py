"""`drape eval intrinsic`: a shipped intrinsic garment space (ONNX) on the dataset's test items.

Test items are held-out parameter sets x held-out motions (`drape sim dataset` splits): nothing of them
was trained on or used to choose a checkpoint. Every figure is against the simulated vertices.

Tables (one per template):
- two_keyframes (Wang et al. Fig. 13): keyframes at the first and last frame of a 96-frame window at
  the end of each test sequence; the in-between frames from drape (the two latents interpolated and
  decoded along the motion; and with the keyframes matched, as the service answers by default: what decoding
  misses of them added back, fading away from them), from linear interpolation of the vertices in character space, and from
  linear interpolation of the shape descriptors (N_E, then N_D); mean vertex error (mm).
- retarget: one keyframe (the middle frame) of (p, m1) encoded, decoded along the other held-out
  motion m2 and compared with the simulation of (p, m2): mean vertex error, Hausdorff (mm), STED;
  beside DeePSD's animation of the template (no keyframe) and decoding the mean training latent.
- invariance: variance of z within a parameter set (over its frames and motions) over the variance of
  the set means, on test items.
- keyframe_ratio (when a dataset of long test sequences exists, `make intrinsic-data-long`): on each
  sequence of >= 300 frames, the fewest evenly spaced keyframes that keep the mean vertex error under
  KEYFRAME_THRESHOLD_MM, for drape (unmatched and matched keyframes) and for vertex interpolation, as % of
  the frames.
- plausibility: share of garment vertices inside the body (closest triangle) of the re-targeted
  sequences before and after refinement (the service's post step), of the simulation, and the edge
  error against the template (mm).

Runs on numpy + ONNX Runtime; DeePSD's rig as the service serves it (drape.runtime.engine.Engine.rig).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.geometry.character_space import character_space_numpy, world_space_numpy
from drape.geometry.metrics import (
    collision_share,
    edge_length_error_mm,
    hausdorff_mm,
    mean_vertex_error_mm,
    sted,
)
from drape.runtime.intrinsic import INTRINSIC_DIR, KEYFRAME_FADE_S, IntrinsicGarment

WINDOW = 96  # frames between and including the two keyframes (Fig. 13)


def _test_items(dataset: Path, template: str) -> list[dict]:
    if not (dataset / "manifest.json").is_file():
        raise FileNotFoundError(f"{dataset}: no simulated dataset here (no manifest.json); the Makefile's "
                                "intrinsic-data targets simulate each one, its test split alone with "
                                "INTRINSIC_SPLITS=test (docs/intrinsic.md)")
    manifest = json.loads((dataset / "manifest.json").read_text())
    items = [it for it in manifest["items"] if it["split"] == "test" and it["garment"] == template]
    if not items:
        raise ValueError(f"{dataset}: no accepted test items of {template!r} (held-out parameters x held-out "
                         "motions); the dataset simulates them after the training items")
    return items


def load_sequence(dataset: Path, item: dict) -> dict:
    """A `drape sim dataset` item's sequence -> {"vertices" (T, N, 3) m world space, "poses" rad (as stored), "trans"
    (T, 3) m, all float64; "fps"}."""
    with np.load(dataset / item["file"], allow_pickle=False) as z:
        return {"vertices": z["vertices"].astype(np.float64), "poses": z["poses"].astype(np.float64),
                "trans": z["trans"].astype(np.float64), "fps": float(z["fps"])}


def two_keyframes(garment: IntrinsicGarment, seq: dict, length: int = WINDOW) -> dict[str, float]:
    """Keyframes at the first and last frame of the last `length` frames of `seq`; mean vertex error (mm)
    of the in-between frames for drape (keyframes unmatched and matched), vertex interpolation and descriptor
    interpolation."""
    v, poses, trans = seq["vertices"], seq["poses"], seq["trans"]
    T = len(v)
    if T < length:
        raise ValueError(f"sequence of {T} frames is shorter than the {length}-frame window")
    a, b = T - length, T - 1
    motion = garment.motion_frames(poses, trans)
    rp, rr = motion.root_position, motion.root_rotation
    cs = character_space_numpy(v, rp, rr)
    t = (np.arange(a, b + 1) - a) / (b - a)  # (length,)
    between = slice(1, length - 1)
    truth = v[a:b + 1][between]

    z = garment.interpolate(list(zip([a, b], garment.encode_at(v[[a, b]], [a, b], motion), strict=True)), T)
    residual = garment.keyframe_residual(v[[a, b]], [a, b], [], z, motion, seq["fps"])
    drape = garment.decode_motion(z, motion)[a:b + 1]
    matched = garment.decode_motion(z, motion, residual=residual)[a:b + 1]
    lerp_cs = (1 - t)[:, None, None] * cs[a] + t[:, None, None] * cs[b]
    vertex = world_space_numpy(lerp_cs, rp[a:b + 1], rr[a:b + 1])
    s = garment.descriptors(cs[[a, b]])
    s_lerp = (1 - t)[:, None] * s[0] + t[:, None] * s[1]
    descriptor = world_space_numpy(garment.shapes(s_lerp), rp[a:b + 1], rr[a:b + 1])
    return {"drape_mm": mean_vertex_error_mm(drape[between], truth),
            "drape_matched_mm": mean_vertex_error_mm(matched[between], truth),
            "vertex_interp_mm": mean_vertex_error_mm(vertex[between], truth),
            "descriptor_interp_mm": mean_vertex_error_mm(descriptor[between], truth)}


KEYFRAME_THRESHOLD_MM = 10.0  # the mean vertex error a keyframed sequence must stay under (stated before measuring)
KEYFRAME_COUNTS = (2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50, 60, 75, 100, 150)


def keyframe_errors(garment: IntrinsicGarment, seq: dict, counts: tuple[int, ...],
                    fades: dict[str, float]) -> dict[str, dict[int, float]]:
    """Mean vertex error (mm) of the whole sequence `seq` from k evenly spaced keyframes (first and last frame
    included), for each k of `counts` up to its length: {"drape": latents alone, <name>: keyframes matched with
    fading time constant fades[name] (seconds), "vertex_interp": linear interpolation of the vertices in
    character space} -> {method: {k: error}}."""
    v, poses, trans = seq["vertices"], seq["poses"], seq["trans"]
    T = len(v)
    motion = garment.motion_frames(poses, trans)
    rp, rr = motion.root_position, motion.root_rotation
    cs = character_space_numpy(v, rp, rr)
    errors: dict[str, dict[int, float]] = {"drape": {}, **{name: {} for name in fades}, "vertex_interp": {}}
    for k in (c for c in counts if c <= T):
        keys = np.unique(np.round(np.linspace(0, T - 1, k)).astype(int))
        z = garment.encode_at(v[keys], keys.tolist(), motion)
        latents = garment.interpolate(list(zip(keys.tolist(), z, strict=True)), T)
        errors["drape"][k] = mean_vertex_error_mm(garment.decode_motion(latents, motion), v)
        for name, fade in fades.items():
            residual = garment.keyframe_residual(v[keys], keys.tolist(), [], latents, motion, seq["fps"], fade)
            errors[name][k] = mean_vertex_error_mm(garment.decode_motion(latents, motion, residual=residual), v)
        j = np.clip(np.searchsorted(keys, np.arange(T), side="right") - 1, 0, len(keys) - 2)
        a = ((np.arange(T) - keys[j]) / (keys[j + 1] - keys[j]))[:, None, None]
        lerp = world_space_numpy((1 - a) * cs[keys[j]] + a * cs[keys[j + 1]], rp, rr)
        errors["vertex_interp"][k] = mean_vertex_error_mm(lerp, v)
    return errors


def keyframe_ratio(garment: IntrinsicGarment, seq: dict, threshold_mm: float = KEYFRAME_THRESHOLD_MM,
                   counts: tuple[int, ...] = KEYFRAME_COUNTS) -> dict:
    """The fewest evenly spaced keyframes (first and last frame included) that keep the mean vertex error of
    the whole sequence under `threshold_mm`, for drape (latents interpolated; keyframes unmatched and matched
    at KEYFRAME_FADE_S) and for linear interpolation of the vertices in character space; as counts and as % of
    the frames (None: not reached by the largest count tried), with each method's error at every count tried."""
    T = len(seq["vertices"])
    errors = keyframe_errors(garment, seq, counts, {"drape_matched": KEYFRAME_FADE_S})
    out: dict = {"frames": T, "threshold_mm": threshold_mm}
    for name, e in errors.items():
        fewest = next((k for k in sorted(e) if e[k] < threshold_mm), None)
        out[f"{name}_keyframes"] = fewest
        out[f"{name}_pct"] = None if fewest is None else 100.0 * fewest / T
        out[f"{name}_errors_mm"] = {str(k): round(x, 2) for k, x in e.items()}
    return out


def _deepsd_poser(garment: IntrinsicGarment, deepsd_dir: Path | None):  # noqa: ANN202
    """DeePSD's animation of the template as the service answers it (POST /v1/outfits/animate without refine):
    the served rig (4 influences, blend shapes refit for them and by the collision fit, Engine.rig) posed by
    the pose network. -> pose(poses (T, 24, 3), trans (T, 3)) -> (T, N, 3) float32, metres."""
    from drape.runtime.deepsd import MODEL_DIR
    from drape.runtime.engine import Engine

    engine = Engine(deepsd_dir or MODEL_DIR, intrinsic_dir=None)
    outfit = engine.rig(garment.template_vertices, garment.faces, garment.body)

    def pose(poses: np.ndarray, trans: np.ndarray) -> np.ndarray:
        return np.concatenate(list(engine.pose_chunks(outfit, poses.astype(np.float32), trans.astype(np.float32))))

    return pose


def _refined(garment: IntrinsicGarment, frames: np.ndarray, poses: np.ndarray, trans: np.ndarray) -> np.ndarray:
    from drape.runtime.engine import RefineSettings, body_surface, posed_body, refine_against

    refiner = RefineSettings().refiner(garment.faces, len(garment.template_vertices))
    return refine_against(frames, body_surface(garment.body), posed_body(garment.body, poses, trans), refiner)


def evaluate(dataset: str | Path, template: str, model_dir: str | Path | None = None,
             deepsd_dir: str | Path | None = None, long_dataset: str | Path | None = None, log=print) -> dict:
    """Every table of one template -> a JSON-able dict (per-row figures and their means). long_dataset: a
    dataset of long (>= 300 frames) test sequences for the keyframe-ratio table (skipped when absent)."""
    dataset = Path(dataset)
    garment = IntrinsicGarment(Path(model_dir) if model_dir else INTRINSIC_DIR / template)
    items = _test_items(dataset, template)
    seqs = {(it["params"], it["motion"]): load_sequence(dataset, it) for it in items}
    body = load_body(garment.body)
    deepsd = _deepsd_poser(garment, Path(deepsd_dir) if deepsd_dir else None)
    mean_latent = np.asarray(garment.latent_mean, np.float32)
    rows_kf, rows_rt, plaus = [], [], []
    latents: dict[int, list[np.ndarray]] = {}
    for (p, m), seq in sorted(seqs.items()):
        row = {"params": p, "motion": m, **two_keyframes(garment, seq)}
        rows_kf.append(row)
        log(f"two keyframes p{p:02d} {m}: " + ", ".join(f"{k} {v:.1f}" for k, v in row.items() if k.endswith("_mm")))
        T = len(seq["vertices"])
        every = garment.encode_frames(seq["vertices"], seq["poses"], seq["trans"])
        latents.setdefault(p, []).append(every)
        for (p2, m2), target in sorted(seqs.items()):
            if p2 != p or m2 == m:
                continue
            k = T // 2
            z = garment.encode(seq["vertices"][k], seq["poses"], seq["trans"], k)
            T2 = len(target["vertices"])
            truth = target["vertices"]
            preds = {"drape": garment.decode(np.repeat(z[None], T2, axis=0), target["poses"], target["trans"]),
                     "mean_latent": garment.decode(np.repeat(mean_latent[None], T2, axis=0), target["poses"],
                                                   target["trans"]),
                     "deepsd": deepsd(target["poses"], target["trans"])}
            r = {"params": p, "keyframe_motion": m, "motion": m2}
            for name, pred in preds.items():
                r[f"{name}_mm"] = mean_vertex_error_mm(pred, truth)
                r[f"{name}_hausdorff_mm"] = hausdorff_mm(pred, truth)
                r[f"{name}_sted"] = sted(pred, truth, garment.faces, target["fps"])["sted"]
            rows_rt.append(r)
            log(f"retarget p{p:02d} {m} -> {m2}: drape {r['drape_mm']:.1f} mm, mean latent "
                f"{r['mean_latent_mm']:.1f}, DeePSD {r['deepsd_mm']:.1f}")
            bodies = body.pose(target["poses"], target["trans"]).astype(np.float64)
            refined = _refined(garment, preds["drape"], target["poses"], target["trans"])
            plaus.append({
                "params": p, "motion": m2,
                "inside_pct": 100 * collision_share(preds["drape"], bodies, body.faces),
                "inside_refined_pct": 100 * collision_share(refined, bodies, body.faces),
                "inside_simulation_pct": 100 * collision_share(truth, bodies, body.faces),
                "edge_error_mm": edge_length_error_mm(preds["drape"], garment.template_vertices, garment.faces),
                "edge_error_refined_mm": edge_length_error_mm(refined, garment.template_vertices, garment.faces),
                "edge_error_simulation_mm": edge_length_error_mm(truth, garment.template_vertices, garment.faces),
            })
    set_means = np.stack([np.concatenate(z).mean(axis=0) for z in latents.values()])
    within = float(np.mean([np.concatenate(z).var(axis=0).mean() for z in latents.values()]))
    between = float(set_means.var(axis=0).mean())

    def means(rows: list[dict]) -> dict[str, float]:
        keys = [k for k in rows[0] if isinstance(rows[0][k], float)]
        return {k: float(np.mean([r[k] for r in rows])) for k in keys}

    ratio: dict = {}
    if long_dataset is not None and (Path(long_dataset) / "manifest.json").exists():
        rows = []
        for it in _test_items(Path(long_dataset), template):
            r = {"params": it["params"], "motion": it["motion"],
                 **keyframe_ratio(garment, load_sequence(Path(long_dataset), it))}
            rows.append(r)
            log(f"keyframe ratio p{it['params']:02d} {it['motion']}: drape {r['drape_keyframes']}, "
                f"matched {r['drape_matched_keyframes']}, vertex interpolation {r['vertex_interp_keyframes']} of {r['frames']} frames")
        ratio = {"dataset": str(long_dataset), "threshold_mm": KEYFRAME_THRESHOLD_MM, "rows": rows}
    return {"template": template, "dataset": str(dataset), "test_items": len(items), "keyframe_ratio": ratio,
            "test_params": sorted({it["params"] for it in items}), "test_motions": sorted({it["motion"] for it in items}),
            "two_keyframes": {"window": WINDOW, "rows": rows_kf, "mean": means(rows_kf)},
            "retarget": {"rows": rows_rt, "mean": means(rows_rt) if rows_rt else {}},
            "invariance": {"within_set_var": within, "between_set_var": between,
                           "ratio": within / max(between, 1e-12)},
            "plausibility": {"rows": plaus, "mean": means(plaus) if plaus else {}}}


def format_table(results: dict) -> str:
    """Markdown tables of `evaluate`'s means."""
    kf, rt, pl, inv = (results["two_keyframes"]["mean"], results["retarget"]["mean"],
                       results["plausibility"]["mean"], results["invariance"])
    lines = [f"### {results['template']}: {results['test_items']} test sequences (parameter sets "
             f"{results['test_params']} x motions {results['test_motions']}, never trained on)", "",
             f"Two keyframes, {results['two_keyframes']['window']} frames (mean vertex error of the in-between "
             "frames, mm):", "",
             "| drape (latent interpolation) | drape, keyframes matched | vertex interpolation | descriptor "
             "interpolation |", "|---|---|---|---|",
             f"| {kf['drape_mm']:.1f} | {kf['drape_matched_mm']:.1f} | {kf['vertex_interp_mm']:.1f} | "
             f"{kf['descriptor_interp_mm']:.1f} |", ""]
    if rt:
        lines += ["Re-targeting (one keyframe of the other held-out motion):", "",
                  "| method | mean vertex error (mm) | Hausdorff (mm) | STED |", "|---|---|---|---|"]
        for name, label in (("drape", "drape (keyframe latent)"), ("mean_latent", "mean training latent"),
                            ("deepsd", "DeePSD (no keyframe)")):
            lines.append(f"| {label} | {rt[f'{name}_mm']:.1f} | {rt[f'{name}_hausdorff_mm']:.1f} | "
                         f"{rt[f'{name}_sted']:.3f} |")
        lines.append("")
    kr = results.get("keyframe_ratio") or {}
    if kr.get("rows"):
        def pct(r: dict, name: str) -> str:
            return "not reached" if r[f"{name}_keyframes"] is None else \
                f"{r[f'{name}_keyframes']} ({r[f'{name}_pct']:.1f}%)"

        lines += [f"Keyframe ratio: fewest evenly spaced keyframes keeping the mean vertex error under "
                  f"{kr['threshold_mm']:g} mm ({kr['dataset']}):", "",
                  "| parameter set | motion | frames | drape | drape, keyframes matched | vertex interpolation |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {r['params']} | {r['motion']} | {r['frames']} | {pct(r, 'drape')} | {pct(r, 'drape_matched')} | "
                  f"{pct(r, 'vertex_interp')} |" for r in kr["rows"]]
        lines.append("")
    lines += [f"Motion invariance: within-set / between-set variance of z = {inv['ratio']:.3f}", ""]
    if pl:
        lines += ["| inside the body, drape | refined | simulation | edge error drape (mm) | refined | simulation |",
                  "|---|---|---|---|---|---|",
                  f"| {pl['inside_pct']:.2f}% | {pl['inside_refined_pct']:.2f}% | {pl['inside_simulation_pct']:.2f}% "
                  f"| {pl['edge_error_mm']:.2f} | {pl['edge_error_refined_mm']:.2f} | "
                  f"{pl['edge_error_simulation_mm']:.2f} |", ""]
    return "\n".join(lines)


def write_results(results: dict, model_dir: str | Path) -> None:
    """Store the table in the model's manifest (`evaluation`), keeping every other field."""
    path = Path(model_dir) / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["evaluation"] = results
    path.write_text(json.dumps(manifest, indent=2) + "\n")
