"""The served rig's collision fit (drape.runtime.collision_fit), chosen on DeePSD's validation split.

Validation only (never the held-out table of `drape eval deepsd`): the shipped config's validation outfits (the
eval's 11 outfit types with seeds 80000 + i on the next body in turn) posed along its validation motions
(procedural seeds 7001, 7002, legs-apart 7101, real CMU 05_04_dance, 06_03_sports, 06_01_walk; 6 frames each),
(the shipped manifest's training config), measured as `drape.training.deepsd_validation` measures a checkpoint: vertices inside the posed body (exact
closest triangle, %), edge error against the template (mm), score = their sum (lower is better). Variants,
each refitting the 4-influence rig's blend shapes to targets at the fit poses:

  served      the rig without a collision fit (what was served before)
  push_gG_rR  R rounds; targets = the posed rig moved G times its push out of the body (`pushed_targets`: each
              vertex within 5 mm of the body, or inside, onto its closest body point + 5 mm)
  refine_gG   one round; the push replaced by the service's refinement of each fit frame
              (drape.geometry.refine.Refiner: a smooth displacement field, stretch relief), moved G times
  push_g3_r1_tight / _deep3 / _tight_deep3: push_g3_r1 on cloth that lies on the body at rest only (pushed fully
              within 1.5 cm of the body's vertices at rest, not at all beyond 3 cm), and/or leaving vertices deeper
              than 3 cm inside where they are
  push_g3_r1_deep3_settle: push_g3_r1_deep3 on the body surface's second reading (the refinement's FAR_K), a
              pushed point that lands within 0.9 x 5 mm of another part put out again (3 rounds); not served yet
  push_g3_r1_deep3_relaxN: push_g3_r1_deep3's targets relaxed toward the rest edge lengths, N Jacobi rounds with
              the pushed vertices held (drape.geometry.edge_relax; collision_fit's `relax`); _repush: then what
              lies within 5 mm of the body pushed out once more (collision_fit's `repush`)

Fit poses: `--poses 150` is `collision_fit.fit_poses()` (every 4th of the sparse rig's 300 clip frames, every 12th
of three procedural training motions); 300 and 600 take every 2nd / 6th and all / every 3rd. Prints per outfit
and the means, with the seconds each fit takes on a 3,000-vertex outfit.
Run: .venv/bin/python -m bench.deepsd_collision_fit [--variants served,push_g3_r1] [--outfits tshirt,jacket]
     [--poses 150] [--posture N] [--fitted]  (all variants, 11 outfits: ~12 minutes on the 2-core machine)
     --posture N: the fit poses also take every 12th frame of N procedural motions with real mocap's upper-back
     and clavicle posture (drape.assets.procedural's `posture`; `collision_fit.fit_poses`'s posture_motions);
     --fitted: the garments of ../shared/data/external fitted onto the neutral body too, on the same validation
     motions, with means of their own (not in the score)
     .venv/bin/python -m bench.deepsd_collision_fit --latency: what a rig request costs with the fit, against the
     same engine without it in the same run (Engine.rig of a t-shirt + trousers of 1k, 10k and 30k vertices on the
     neutral body; the median of 3 cold rigs each, the content cache cleared between them)
     .venv/bin/python -m bench.deepsd_collision_fit --where [--outfits ...]: where the served rig without the fit
     leaves cloth inside the body on the validation split: the share of inside vertices whose closest body point,
     2 mm out along its normal, is still inside the body (the body overlapping itself), the share the nearest body
     vertex's normal calls outside (DeePSD's training collider), depth percentiles (mm) and the joints that skin
     the nearest body vertex most
     .venv/bin/python -m bench.deepsd_collision_fit --pushes [--outfits dress,tshirt]: how far the plain push moves
     cloth at the fit poses (share of vertex-frames pushed, percentiles mm) and how the push divides by how far
     each vertex lies from the body's vertices at rest (< 1.5 cm, 1.5-3 cm, beyond)
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator

import numpy as np

from drape.assets.body import Body, load_body
from drape.assets.procedural import generate_motion
from drape.geometry.refine import FAR_K, BodySurface, Refiner, RefineReport
from drape.runtime import collision_fit as cf
from drape.runtime.deepsd import DeePSDModel, Rig, pose_outfit
from drape.runtime.sparse_rig import fit_poses as clip_poses
from drape.runtime.sparse_rig import sparse_rig
from drape.training.deepsd_data import OutfitSpec, load_outfit
from drape.training.deepsd_validation import measure_poser, summarise, validation_specs

VARIANTS: dict[str, tuple] = {  # name: (targets, rounds, gain[, pushed_targets keywords])
    "served": (None, 0, 0.0),
    "push_g1_r1": ("push", 1, 1.0), "push_g1_r2": ("push", 2, 1.0), "push_g1_r3": ("push", 3, 1.0),
    "push_g2_r2": ("push", 2, 2.0), "push_g3_r1": ("push", 1, 3.0), "push_g5_r1": ("push", 1, 5.0),
    "refine_g1": ("refine", 1, 1.0), "refine_g3": ("refine", 1, 3.0),
    # only cloth lying on the body at rest (fully nearer than 1.5 cm, none beyond 3 cm), no vertex deeper than 3 cm
    "push_g3_r1_tight": ("push", 1, 3.0, {"tight": (0.015, 0.03)}),
    "push_g3_r1_deep3": ("push", 1, 3.0, {"deepest": 0.03}),
    # the served fit (push_g3_r1_deep3) at a lower gain: re-chosen for DeePSD 0.11.0, which leaves less inside
    "push_g1_r1_deep3": ("push", 1, 1.0, {"deepest": 0.03}), "push_g2_r1_deep3": ("push", 1, 2.0, {"deepest": 0.03}),
    "push_g3_r1_tight_deep3": ("push", 1, 3.0, {"tight": (0.015, 0.03), "deepest": 0.03}),
    # push_g3_r1_deep3 on the body surface's second reading, pushed points that land within 0.9 eps of another
    # part put out again (up to 3 rounds): not served yet (docs/deepsd_experiments.md)
    "push_g3_r1_deep3_settle": ("push", 1, 3.0, {"deepest": 0.03, "far_k": FAR_K, "settle": 3}),
    # the served fit with N rounds of edge-length relaxation on its targets, pushed vertices held (collision_fit's relax)
    **{f"push_g3_r1_deep3_relax{n}": ("push", 1, 3.0, {"deepest": 0.03, "relax": n}) for n in (5, 10, 20, 40)},
    # the same, then what the relaxation drew back within 5 mm of the body pushed out once more (gain 1)
    **{f"push_g3_r1_deep3_relax{n}_repush": ("push", 1, 3.0, {"deepest": 0.03, "relax": n, "repush": True})
       for n in (10, 20, 40)},
    # relax20_repush with only stretched edges shortened, and/or cloth within 1.5 cm of the body's vertices at rest held
    "push_g3_r1_deep3_relax20s_repush": ("push", 1, 3.0, {"deepest": 0.03, "relax": 20, "repush": True,
                                                          "stretch_only": True}),
    "push_g3_r1_deep3_relax20h_repush": ("push", 1, 3.0, {"deepest": 0.03, "relax": 20, "repush": True,
                                                          "hold": 0.015}),
    "push_g3_r1_deep3_relax20sh_repush": ("push", 1, 3.0, {"deepest": 0.03, "relax": 20, "repush": True,
                                                           "stretch_only": True, "hold": 0.015}),
}
STRIDES = {150: (4, 12), 300: (2, 6), 600: (1, 3)}  # fit poses: (clip frame stride, procedural frame stride)


def poses_for(count: int, posture: int = 0) -> np.ndarray:
    """The fit poses: `count` (150: `collision_fit.fit_poses(0)`), then every 12th frame of `posture` procedural
    motions with real mocap's posture (`collision_fit.fit_poses`'s posture_motions)."""
    clip, proc = STRIDES[count]
    procedural = np.concatenate([generate_motion(300, seed=s).poses for s in cf.PROCEDURAL_SEEDS])
    return np.concatenate([clip_poses()[::clip], procedural[::proc], cf.posture_poses(posture)]).astype(np.float64)


def fitted_outfits(body_name: str) -> Iterator[tuple[OutfitSpec, np.ndarray, np.ndarray, Body]]:
    """The garments made outside the project for other bodies (`drape eval deepsd`'s EXTERNAL_GARMENTS, absent:
    none), fitted onto `body_name` as that evaluation fits them."""
    from pathlib import Path

    from drape.training.deepsd_eval import EXTERNAL_GARMENTS, fitted_garment

    body = load_body(body_name)
    for path in sorted(Path(EXTERNAL_GARMENTS).glob("*.obj")) if Path(EXTERNAL_GARMENTS).is_dir() else []:
        verts, faces = fitted_garment(path, body)
        yield OutfitSpec(path.stem, len(verts), 0, body_name), verts, faces, body


def refined_targets(verts: np.ndarray, faces: np.ndarray, rig: Rig, body: Body, poses: np.ndarray,
                    keys: np.ndarray) -> np.ndarray:
    """The rig posed at the fit poses, each frame refined out of the body (the near part, as `pushed_targets`)."""
    posed = pose_outfit(verts, rig, keys, body.joints, poses)
    used, faces_near = cf.body_near(verts, body.vertices, body.faces)
    skin = Rig(body.weights[used].astype(np.float32), np.zeros((1, len(used), 3), np.float32))
    bodies = pose_outfit(body.vertices[used], skin, np.zeros((len(poses), 1), np.float32), body.joints, poses)
    surface, refiner, report = BodySurface(faces_near, len(used)), Refiner(faces, len(verts)), RefineReport()
    return np.stack([refiner.refine_frame(posed[t].astype(np.float64), bodies[t].astype(np.float64), surface, report)
                     for t in range(len(poses))]).astype(np.float32)


def fit_variant(name: str, verts: np.ndarray, faces: np.ndarray, rig: Rig, body: Body, poses: np.ndarray,
                keys: np.ndarray) -> Rig:
    targets, rounds, gain, *extra = VARIANTS[name]
    if targets == "push":  # the served function, with the variant's settings in place of the served ones
        options = {"deepest": None, "far_k": None, "settle": 0, "relax": 0, "repush": False, "hold": None,
                   **(extra[0] if extra else {})}
        return cf.collision_fit(verts, rig, body.joints, 4, poses, keys, body.vertices, body.faces, body.weights,
                                rounds=rounds, gain=gain, faces=faces, **options)
    for _ in range(rounds):  # the service's refinement of each fit frame as the targets
        posed = pose_outfit(verts, rig, keys, body.joints, poses)
        moved = refined_targets(verts, faces, rig, body, poses, keys)
        rig = sparse_rig(verts, rig, body.joints, 4, poses, keys, targets=posed + np.float32(gain) * (moved - posed))
    return rig


def validation_outfits(cfg: dict, outfits: list[str] | None) -> Iterator[tuple[OutfitSpec, np.ndarray, np.ndarray, Body]]:
    """The config's validation outfits (those of the types in `outfits`, '+' joining layers; all when None) ->
    (spec, vertices (N, 3) m, faces, body) each."""
    for spec in validation_specs(cfg):
        if outfits is None or spec.types.replace(",", "+") in outfits:
            verts, faces = load_outfit(spec)
            yield spec, verts, faces, load_body(spec.body)


def poser(model: DeePSDModel, verts: np.ndarray, rig: Rig, body: Body):  # noqa: ANN201
    return lambda ps, tr: pose_outfit(verts, rig, model.pose_keys(ps), body.joints, ps, tr)


def latency() -> None:
    from drape.assets.outfits import generate_outfit
    from drape.runtime.cache import LRUBytesCache
    from drape.runtime.engine import Engine

    engines = {"without": Engine(refine_workers=1, collision_fit=False), "with": Engine(refine_workers=1)}
    for e in engines.values():
        e.warm_up()
    print("rig latency (s): without the collision fit | with it | ratio")
    for n in (1000, 10000, 30000):
        o = generate_outfit(["tshirt", "trousers"], vertices=n, seed=5)
        t = {}
        for name, e in engines.items():
            runs = []
            for _ in range(3):
                e.cache = LRUBytesCache(e.cache.max_bytes)  # a cold rig each time
                t0 = time.perf_counter()
                e.rig(o.vertices, o.faces, "neutral")
                runs.append(time.perf_counter() - t0)
            t[name] = float(np.median(runs))
        print(f"  {len(o.vertices):6d} vertices: {t['without']:.3f} | {t['with']:.3f} | {t['with'] / t['without']:.1f}x",
              flush=True)
    for e in engines.values():
        e.close()


def where(outfits: list[str] | None) -> None:
    from collections import Counter

    from scipy.spatial import cKDTree

    from drape.geometry.mesh import vertex_normals
    from drape.geometry.queries import MeshDistance, signed_distance_nearest_vertex
    from drape.geometry.skeleton import JOINT_NAMES
    from drape.training.deepsd_validation import validation_motions

    model = DeePSDModel()
    cfg = model.manifest["training"]["config"]
    clip_fit = clip_poses()
    clip_keys = model.pose_keys(clip_fit)
    for spec, verts, faces, body in validation_outfits(cfg, outfits):
        rig = sparse_rig(verts, model.rig(verts, faces, body), body.joints, 4, clip_fit, clip_keys)
        total = inside = overlap = nearest_out = 0
        depths: list[float] = []
        joints: Counter = Counter()
        for motion in validation_motions(cfg, spec.body):
            fr = np.linspace(0, motion.num_frames - 1, cfg["validation"]["frames_per_clip"]).round().astype(int)
            ps, tr = motion.poses[fr].astype(np.float64), motion.trans[fr].astype(np.float64)
            posed = pose_outfit(verts, rig, model.pose_keys(ps), body.joints, ps, tr)
            for g, b in zip(posed.astype(np.float64), body.pose(ps, tr).astype(np.float64), strict=True):
                normals = vertex_normals(b, body.faces)
                dist = MeshDistance(b, body.faces, normals)
                sd = dist.signed_distance(g)
                mask = sd < 0
                total += len(g)
                inside += int(mask.sum())
                if mask.any():
                    cp, n, _ = dist.closest(g[mask])
                    overlap += int((dist.signed_distance(cp + 0.002 * n) < 0).sum())
                    nearest_out += int((signed_distance_nearest_vertex(g[mask], b, normals)[0] >= 0).sum())
                    depths += list(-1000 * sd[mask])
                    near = cKDTree(b).query(g[mask])[1]
                    joints.update(JOINT_NAMES[j] for j in body.weights[near].argmax(axis=1))
        d = np.array(depths) if depths else np.zeros(1)
        share = max(inside, 1)
        print(f"{spec.key}: inside {100 * inside / total:.2f}%; of those in the body's overlap "
              f"{100 * overlap / share:.0f}%, outside by the nearest vertex {100 * nearest_out / share:.0f}%; depth mm "
              f"p50 {np.median(d):.1f} p90 {np.quantile(d, 0.9):.1f} max {d.max():.1f}; joints "
              + ", ".join(f"{j} {100 * c / share:.0f}%" for j, c in joints.most_common(4)), flush=True)


def pushes(outfits: list[str] | None) -> None:
    from scipy.spatial import cKDTree

    model = DeePSDModel()
    cfg = model.manifest["training"]["config"]
    poses = cf.fit_poses()
    keys = model.pose_keys(poses)
    for spec, verts, faces, body in validation_outfits(cfg, outfits):
        rig = model.rig(verts, faces, body)
        posed = pose_outfit(verts, rig, keys, body.joints, poses)
        moved = cf.pushed_targets(verts, rig, body.joints, poses, keys, body.vertices, body.faces, body.weights)
        d = np.linalg.norm(moved - posed, axis=2)  # (T, N) m
        gap = cKDTree(body.vertices).query(verts)[0]
        q = 1000 * np.quantile(d[d > 0], [0.5, 0.9, 0.99, 1.0])
        bands = []
        for lo, hi in ((0.0, 0.015), (0.015, 0.03), (0.03, np.inf)):
            sel = (gap >= lo) & (gap < hi)
            bands.append(f"{lo * 100:.1f}-{hi * 100:.1f} cm: {sel.sum()} vertices, {100 * np.mean(d[:, sel] > 0):.2f}% "
                         f"pushed, {d[:, sel].sum() / d.sum():.2f} of the push")
        print(f"{spec.key}: {100 * np.mean(d > 0):.2f}% of vertex-frames pushed, mm p50 {q[0]:.1f} p90 {q[1]:.1f} "
              f"p99 {q[2]:.1f} max {q[3]:.1f}; by rest distance: " + "; ".join(bands), flush=True)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--outfits", default=None, help="comma list of outfit types, '+' joining layers (default: all 11)")
    p.add_argument("--poses", type=int, default=150, choices=sorted(STRIDES))
    p.add_argument("--posture", type=int, default=cf.POSTURE_MOTIONS,
                   help="fit poses also from this many procedural motions with real mocap's posture")
    p.add_argument("--fitted", action="store_true",
                   help="also the garments of ../shared/data/external, fitted onto the neutral body (own means)")
    p.add_argument("--latency", action="store_true", help="time rig requests with and without the fit instead")
    p.add_argument("--where", action="store_true", help="where the rig without the fit leaves cloth inside")
    p.add_argument("--pushes", action="store_true", help="how far the plain push moves cloth at the fit poses")
    args = p.parse_args()
    outfits = args.outfits.split(",") if args.outfits else None
    if args.pushes:
        pushes(outfits)
        return
    if args.latency:
        latency()
        return
    if args.where:
        where(outfits)
        return
    names = args.variants.split(",")
    model = DeePSDModel()
    cfg = model.manifest["training"]["config"]  # the shipped model's own validation split
    poses = poses_for(args.poses, args.posture)
    keys = model.pose_keys(poses)
    clip_fit = clip_poses()
    clip_keys = model.pose_keys(clip_fit)
    rows: dict[str, list[dict]] = {n: [] for n in names}
    seconds: dict[str, list[float]] = {n: [] for n in names}
    print(f"validation ({len(poses)} fit poses): inside % / edge error mm / fit seconds")
    fitted: dict[str, list[dict]] = {n: [] for n in names}
    outfit_list = [(False, o) for o in validation_outfits(cfg, outfits)]
    outfit_list += [(True, o) for o in fitted_outfits("neutral")] if args.fitted else []
    for is_fitted, (spec, verts, faces, body) in outfit_list:
        served = sparse_rig(verts, model.rig(verts, faces, body), body.joints, 4, clip_fit, clip_keys)
        line = []
        for n in names:
            t0 = time.perf_counter()
            rig = fit_variant(n, verts, faces, served, body, poses, keys)
            seconds[n].append(time.perf_counter() - t0)
            r = measure_poser(cfg, verts, faces, spec.body, body, poser(model, verts, rig, body))
            (fitted if is_fitted else rows)[n].append(r)
            line.append(f"{n} {r['inside_triangle_pct']:.2f}% {r['edge_error_mm']:.2f}mm {seconds[n][-1]:.1f}s")
        print(f"{spec.key:38s} " + " | ".join(line), flush=True)
    base = summarise(rows[names[0]])["score"]
    print(f"\nmeans over outfits (score ratio to {names[0]}):")
    for n in names:
        s = summarise(rows[n])
        print(f"  {n:12s} inside {s['inside_triangle_pct']:.2f}%  edge {s['edge_error_mm']:.3f} mm  score "
              f"{s['score']:.3f} ({s['score'] / base:.3f}x)  fit {np.mean(seconds[n]):.1f} s")
    if args.fitted and fitted[names[0]]:
        print("means over the fitted garments (not in the score above):")
        for n in names:
            s = summarise(fitted[n])
            print(f"  {n:12s} inside {s['inside_triangle_pct']:.2f}%  edge {s['edge_error_mm']:.3f} mm  score "
                  f"{s['score']:.3f}")


if __name__ == "__main__":
    main()
