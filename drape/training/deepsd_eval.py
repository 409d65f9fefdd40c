"""`drape eval deepsd`: the shipped DeePSD (ONNX) on held-out outfits x held-out clips.

Methods, per outfit:
  baseline: LBS with blend weights copied from the nearest body vertex, no PSD;
  no_chi:   drape's weights + D_data only (the model without its physics branch);
  model:    drape's dense weights (24 a vertex) + D = D_data + D_phys (the network's own rig);
  served:   the model's rig as the service serves it by default: 4 influences a vertex, blend shapes
            refit for them (drape.runtime.sparse_rig) and to keep the garment out of the body
            (drape.runtime.collision_fit); served8: the same with 8 influences.
Metrics over the evaluated frames: collision share (garment vertices inside the
body, signed distance < 0; nearest-vertex and closest-triangle variants), mean
edge-length error vs the template (mm), bending (1 - cos of neighbouring face normals).
When a simulated dataset exists (`make sim-dataset` writes `data/sim/skirt`), each method
also poses the dataset's garment along its sequences on held-out clips, and the mean vertex
error (mm) against the simulated vertices is reported per clip. Runs on numpy + ONNX Runtime
(and trimesh to read the dataset's garment).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.geometry.lbs import pose_mesh
from drape.geometry.mesh import vertex_normals
from drape.geometry.metrics import bending, edge_length_error_mm
from drape.geometry.queries import (
    MeshDistance,
    nearest_vertex_weights,
    signed_distance_nearest_vertex,
)
from drape.runtime.collision_fit import served_fit_frames, served_rig
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, Rig, pose_outfit
from drape.training import DEFAULT_GROUND_TRUTH
from drape.training.config_file import read_config
from drape.training.deepsd_data import OutfitSpec, eval_specs, load_outfit

METHODS = ("baseline", "no_chi", "model", "served", "served8")
LOOSE = ("skirt", "dress")


def method_poser(model: DeePSDModel, verts: np.ndarray, faces: np.ndarray, body):  # noqa: ANN001, ANN201
    """One outfit rigged by every method; returns pose(poses (T, 24, 3), trans (T, 3)) -> {method: (T, N, 3)}."""
    rig = model.rig(verts, faces, body)
    fit, collision = served_fit_frames(model.pose_keys)
    rigs = {"model": rig, "no_chi": Rig(rig.weights, model.blend_shapes_data(verts, faces, body)),
            "served": served_rig(verts, rig, body, 4, fit, collision, faces),
            "served8": served_rig(verts, rig, body, 8, fit, collision, faces)}
    base_w = nearest_vertex_weights(verts, body.vertices, body.weights)

    def pose(poses: np.ndarray, trans: np.ndarray) -> dict[str, np.ndarray]:
        keys = model.pose_keys(poses)
        return {
            "baseline": pose_mesh(verts, base_w, body.joints, poses, trans),
            **{m: pose_outfit(verts, r, keys, body.joints, poses, trans) for m, r in rigs.items()},
        }

    return pose


REAL_CLIPS = ("02_01_walk", "05_02_dance", "06_02_sports")  # real CMU mocap, never trained on
UNSEEN_BODY = "heavy"  # a body preset DeePSD never trained on (drape/assets/body_bake.py)
UNSEEN_BODY_OUTFITS = ("tshirt", "trousers", "dress")
REAL_MOCAP = Path("..") / "shared" / "data" / "mocap"
# garments made outside the project for other bodies (ArcSim tops; provenance in that folder), fitted onto FITTED_BODY
EXTERNAL_GARMENTS = Path("..") / "shared" / "data" / "external"
FITTED_BODY = "neutral"
METRICS = ("collision_nearest_vertex_pct", "collision_triangle_pct", "edge_error_mm", "bending")


def _real_motion(path: Path, body, cache: dict):  # noqa: ANN001, ANN202
    """A real BVH imported onto `body` at 30 fps, feet on the floor (drape.assets.motion.import_motion)."""
    from drape.assets.motion import import_motion

    key = (path, body.name)
    if key not in cache:
        cache[key] = import_motion(path.read_bytes(), body, fps=30.0, name=path.stem).motion
    return cache[key]


def evaluate(config_path: str | Path, model_dir: str | Path = MODEL_DIR, log=print,
             ground_truth: str | Path | None = DEFAULT_GROUND_TRUTH,
             real_mocap: str | Path | None = REAL_MOCAP,
             external: str | Path | None = EXTERNAL_GARMENTS) -> dict:
    """Evaluate and return {"rows": [...], "settings": {...}, "mean": ..., "mean_real": ..., "mean_unseen_body":
    ..., "mean_fitted": ...}; each row: outfit, body, method, set ("deepmimic": held-out outfits x the held-out
    embedded clips; "cmu": the same outfits x real CMU mocap from `real_mocap`, skipped when the folder is absent;
    "unseen_body": UNSEEN_BODY_OUTFITS made for the UNSEEN_BODY x the held-out embedded clips; "fitted_cmu": each
    garment mesh (*.obj) of `external`, made for another body, fitted onto FITTED_BODY (drape.geometry.fitting, its
    defaults) x the same real CMU clips, skipped when either folder is absent), metrics."""
    cfg = read_config(config_path, "deepsd")
    model = DeePSDModel(model_dir)
    real_dir = Path(real_mocap) if real_mocap else None
    real = [real_dir / f"{c}.bvh" for c in REAL_CLIPS] if real_dir and real_dir.is_dir() else []
    imported: dict = {}
    rows = []
    unseen = [OutfitSpec(t, cfg["eval_vertices"], 90100 + i, UNSEEN_BODY) for i, t in enumerate(UNSEEN_BODY_OUTFITS)]
    for spec in [*eval_specs(cfg), *unseen]:
        verts, faces = load_outfit(spec)
        body = load_body(spec.body)
        pose = method_poser(model, verts, faces, body)
        clips = [load_clip(c) for c in cfg["heldout_clips"]]
        groups = ({"unseen_body": clips} if spec.body == UNSEEN_BODY else
                  {"deepmimic": clips, "cmu": [_real_motion(p, body, imported) for p in real]})
        for group, motions in groups.items():
            if not motions:
                continue
            acc = _accumulate(pose, body, motions, cfg["eval_frames_per_clip"], verts, faces)
            rows += _rows(acc, spec.types, spec.body, len(verts), group, len(motions))
        log(f"{spec.types:18s} done")
    fitted = sorted(Path(external).glob("*.obj")) if external and Path(external).is_dir() and real else []
    body = load_body(FITTED_BODY)
    for path in fitted:
        verts, faces = fitted_garment(path, body)
        acc = _accumulate(method_poser(model, verts, faces, body), body,
                          [_real_motion(p, body, imported) for p in real], cfg["eval_frames_per_clip"], verts, faces)
        rows += _rows(acc, path.stem, FITTED_BODY, len(verts), "fitted_cmu", len(real))
        log(f"{path.stem:18s} done")
    gt = ground_truth_error(ground_truth, cfg["heldout_clips"], model) if ground_truth else None

    def means(group: str) -> dict:
        return {m: {k: float(np.mean([r[k] for r in rows if r["method"] == m and r["set"] == group]))
                    for k in METRICS} for m in METHODS}

    return {
        **({"ground_truth": gt} if gt else {}),
        "settings": {"heldout_clips": cfg["heldout_clips"], "frames_per_clip": cfg["eval_frames_per_clip"],
                     "outfits": [s.key for s in eval_specs(cfg)],
                     "real_clips": [p.stem for p in real], "unseen_body": UNSEEN_BODY,
                     "unseen_body_outfits": [s.key for s in unseen],
                     "fitted_garments": [p.stem for p in fitted], "fitted_body": FITTED_BODY},
        "rows": rows,
        "mean": means("deepmimic"),
        **({"mean_real": means("cmu")} if real else {}),
        "mean_unseen_body": means("unseen_body"),
        **({"mean_fitted": means("fitted_cmu")} if fitted else {}),
    }


def fitted_garment(path: Path, body) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    """A garment mesh file made for another body, fitted onto `body` -> vertices (N, 3) float32 m, faces (F, 3)."""
    from drape.geometry.fitting import fit_garment
    from drape.geometry.mesh_io import load_mesh

    v, f = load_mesh(path)
    return fit_garment(v, f, body).vertices, f


def _rows(acc: dict, outfit: str, body: str, vertices: int, group: str, clips: int) -> list[dict]:
    """One table row per method from `_accumulate`'s lists over `clips` motions of equal frame counts."""
    return [{
        "outfit": outfit, "body": body, "vertices": int(vertices), "method": m, "set": group,
        "collision_nearest_vertex_pct": 100 * float(np.mean(acc[m]["inside_nv"])),
        "collision_triangle_pct": 100 * float(np.mean(acc[m]["inside_tri"])),
        "edge_error_mm": float(np.mean(acc[m]["edge"])),
        "bending": float(np.mean(acc[m]["bend"])),
        # closest-triangle inside % of each motion of the set, in order
        "clip_triangle_pct": [100 * float(x) for x in np.reshape(acc[m]["inside_tri"], (clips, -1)).mean(1)],
    } for m in METHODS]


def _accumulate(pose, body, motions: list, frames_per_clip: int, verts: np.ndarray,  # noqa: ANN001
                faces: np.ndarray) -> dict[str, dict[str, list[float]]]:
    """Every method's per-frame collision shares and per-clip edge error and bending over the motions."""
    acc: dict[str, dict[str, list[float]]] = {m: {"inside_nv": [], "inside_tri": [], "edge": [], "bend": []}
                                              for m in METHODS}
    for motion in motions:
        frames = np.linspace(0, motion.num_frames - 1, frames_per_clip).round().astype(int)
        poses, trans = motion.poses[frames].astype(np.float64), motion.trans[frames].astype(np.float64)
        posed = pose(poses, trans)
        body_frames = body.pose(poses, trans)
        for t in range(len(frames)):
            bt = body_frames[t].astype(np.float64)
            normals = vertex_normals(bt, body.faces)
            dist = MeshDistance(bt, body.faces, normals)
            for m in METHODS:
                g = posed[m][t].astype(np.float64)
                acc[m]["inside_tri"].append(float(np.mean(dist.signed_distance(g) < 0)))
                sd_nv, _ = signed_distance_nearest_vertex(g, bt, normals)
                acc[m]["inside_nv"].append(float(np.mean(sd_nv < 0)))
        for m in METHODS:
            acc[m]["edge"].append(edge_length_error_mm(posed[m], verts, faces))
            acc[m]["bend"].append(bending(posed[m], faces))
    return acc


def ground_truth_error(sim_dir: str | Path, clips: list[str], model: DeePSDModel) -> dict | None:
    """Mean vertex error (mm) of each method against simulated sequences on the given clips.

    sim_dir holds a `drape sim dataset` output: manifest.json, items/*.npz with vertices (T, N, 3)
    float32 m, poses (T, 24, 3), trans (T, 3), and the garment mesh `<garment>.obj` beside them.
    Returns None when there is no dataset or no accepted item on these clips.
    """
    from drape.geometry.mesh_io import load_mesh

    sim_dir = Path(sim_dir)
    manifest_path = sim_dir / "manifest.json"
    if not manifest_path.exists():
        return None
    manifest = json.loads(manifest_path.read_text())
    body = load_body(manifest["body"])
    items = [it for it in manifest["items"] if it["motion"] in clips]
    if not items:
        return None
    errors: dict[str, dict[str, list[float]]] = {}
    for garment in sorted({it["garment"] for it in items}):
        verts, faces = load_mesh(sim_dir / f"{garment}.obj")
        pose = method_poser(model, verts, faces, body)
        for it in (i for i in items if i["garment"] == garment):
            with np.load(sim_dir / it["file"], allow_pickle=False) as z:
                truth, poses, trans = z["vertices"], z["poses"].astype(np.float64), z["trans"].astype(np.float64)
                if not np.array_equal(z["faces"], faces):
                    raise ValueError(f"{it['file']}: faces differ from {garment}.obj")
            posed = pose(poses, trans)
            for m in METHODS:
                err = float(np.linalg.norm(posed[m] - truth, axis=-1).mean() * 1e3)
                errors.setdefault(it["motion"], {k: [] for k in METHODS})[m].append(err)
    return {
        "dataset": str(sim_dir), "garments": sorted({it["garment"] for it in items}), "body": manifest["body"],
        "rows": [{"clip": c, "sequences": len(e["model"]), **{m: float(np.mean(e[m])) for m in METHODS}}
                 for c, e in sorted(errors.items())],
    }


def format_table(results: dict) -> str:
    """Markdown table: one row per outfit and method, then the means."""
    head = ("| outfit | method | inside, nearest vertex (%) | inside, closest triangle (%) "
            "| edge error (mm) | bending |\n|---|---|---|---|---|---|")
    lines = [head]

    def table(group: str, mean: dict) -> None:
        for r in results["rows"]:
            if r.get("set", "deepmimic") == group:
                lines.append(f"| {r['outfit']} | {r['method']} | {r['collision_nearest_vertex_pct']:.2f} "
                             f"| {r['collision_triangle_pct']:.2f} | {r['edge_error_mm']:.2f} | {r['bending']:.4f} |")
        for m, v in mean.items():
            lines.append(f"| **mean** | {m} | {v['collision_nearest_vertex_pct']:.2f} "
                         f"| {v['collision_triangle_pct']:.2f} | {v['edge_error_mm']:.2f} | {v['bending']:.4f} |")
        worst = {m: max((max(r["clip_triangle_pct"]), r["outfit"]) for r in results["rows"]
                        if r.get("set", "deepmimic") == group and r["method"] == m and r.get("clip_triangle_pct"))
                 for m in mean}
        if worst:
            lines.append("\nWorst single clip, inside (closest triangle): " + "; ".join(
                f"{m} {pct:.2f}% ({outfit})" for m, (pct, outfit) in worst.items()) + ".")

    table("deepmimic", results["mean"])
    if results.get("mean_real"):
        lines.append(f"\nThe same outfits on real CMU mocap ({', '.join(results['settings']['real_clips'])}; "
                     "imported at 30 fps onto each outfit's body, feet on the floor; never trained on):\n")
        lines.append(head)
        table("cmu", results["mean_real"])
    if results.get("mean_unseen_body"):
        lines.append(f"\nOutfits made for a body never trained on (`{results['settings']['unseen_body']}`: "
                     "heavier and taller), on the held-out clips:\n")
        lines.append(head)
        table("unseen_body", results["mean_unseen_body"])
    if results.get("mean_fitted"):
        lines.append(f"\nGarments made outside the project for other bodies "
                     f"({', '.join(results['settings']['fitted_garments'])}), fitted onto "
                     f"`{results['settings']['fitted_body']}` (drape.geometry.fitting), on the same real CMU clips:\n")
        lines.append(head)
        table("fitted_cmu", results["mean_fitted"])
    gt = results.get("ground_truth")
    if gt:
        lines.append(f"\nMean vertex error (mm) against simulated sequences ({', '.join(gt['garments'])} on "
                     f"{gt['body']}, `{gt['dataset']}`, every accepted parameter set):\n")
        lines.append("| clip | sequences | " + " | ".join(METHODS) + " |\n|---|---|" + "---|" * len(METHODS))
        for r in gt["rows"]:
            lines.append(f"| {r['clip']} | {r['sequences']} | " + " | ".join(f"{r[m]:.1f}" for m in METHODS) + " |")
    s = results["settings"]
    lines.append(f"\nHeld-out clips {', '.join(s['heldout_clips'])}, {s['frames_per_clip']} frames each; "
                 f"held-out outfits {', '.join(s['outfits'])}.")
    return "\n".join(lines)


def write_results(results: dict, model_dir: str | Path = MODEL_DIR,
                  doc: str | Path = Path("docs") / "deepsd_eval.md") -> list[Path]:
    """Store the table in the model's manifest and in docs/."""
    manifest_path = Path(model_dir) / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    manifest["evaluation"] = results
    manifest_path.write_text(json.dumps(manifest, indent=2) + "\n")
    doc = Path(doc)
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text("# DeePSD evaluation (`drape eval deepsd --write`)\n\n" + format_table(results) + "\n")
    return [manifest_path, doc]
