"""Does a collision fit help the layer networks' rigs, as it helps DeePSD's served rig? Measured on the layer
networks' own validation splits, never on `drape eval layers`' held-out motions.

Each layer network ends in a linear rig (weights + blend shapes driven by its keys: drape.runtime.layers), so the
served DeePSD rig's trick applies: at fit frames (training motions: the embedded clips DeePSD and the layer
networks trained on, drape.runtime.sparse_rig.FIT_CLIPS, and three procedural motions, seeds 501-503), pose both
layers, put them through the post step between layers (drape.geometry.layers.LayerRefiner: inner out of the body,
outer out of the body and of the inner layer), and refit each layer's blend shapes by the same ridge solve to its
posed vertices moved `gain` times toward that result (drape.runtime.sparse_rig.sparse_rig with targets). The
weights do not change. The outer network's keys depend on the thickness: its fit frames are taken at each of
`--thickness`.

Figures, per combination and variant (none: the shipped rigs):
- inner: drape.training.layers_inner.measure on the inner network's validation split (inside % + edge error mm);
- outer: drape.training.layers_outer.measure_all on its validation sequences (`make layers-data`'s test split:
  held-out H_in x the held-out procedural motion; RMSE mm, L-Coll %, H-Coll %) and its real validation clips.

Variants: none (the shipped rigs), gainG (both rigs fitted), and with --inner-only gainG_inner (the inner rig
fitted by drape.training.layers_inner_fit, what `drape train mgn-inner-fit` serves, the outer network's rig as shipped: the outer network's keys read the inner network's, which a refit of
the inner rig's blend shapes does not change).

Run: PYTHONPATH=. .venv/bin/python -m bench.layers_collision_fit [--gains 1,3] [--stride 6] [--inner-only]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np

from drape.assets.motion import load_clip
from drape.assets.procedural import generate_motion
from drape.geometry.layers import LayerRefiner
from drape.runtime.deepsd import Rig, pose_outfit
from drape.runtime.layers import OUTER_MODELS, OuterModel
from drape.runtime.sparse_rig import FIT_CLIPS, sparse_rig
from drape.training import layers_inner, layers_outer

PAIRS = (("tshirt", "jacket"), ("tanktop", "longsleeve"))
PROCEDURAL_SEEDS = (501, 502, 503)


def fit_motions(task: layers_outer.OuterTask, real: int) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The fit motions: (poses (T, 24, 3) rad, trans (T, 3) m, fps); with `real` > 0 also the first `real` frames
    of each real CMU clip the outer network trained on (its config's mocap.train)."""
    out = []
    if real:
        for clip in task.clip_sequences(task.cfg["mocap"]["train"], 0.008, real):
            out.append((clip.poses, clip.trans, float(task.cfg["mocap"]["fps"])))
    for name in FIT_CLIPS:
        c = load_clip(name)
        out.append((c.poses.astype(np.float32), c.trans.astype(np.float32), float(c.fps)))
    for s in PROCEDURAL_SEEDS:
        m = generate_motion(300, seed=s)
        out.append((m.poses.astype(np.float32), m.trans.astype(np.float32), float(m.fps)))
    return out


def fit_frames(task: layers_outer.OuterTask, outer_model: OuterModel, thicknesses: list[float], stride: int,
               real: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every `stride`-th frame of the fit motions at each thickness -> (poses (T, 24, 3), inner keys (T, Ki),
    outer keys (T, Ko), thickness (T,))."""
    poses, ik, ok, th = [], [], [], []
    for p, t, fps in fit_motions(task, real):
        inner_keys = task.inner_model.pose_keys(p)
        for h in thicknesses:
            keys = outer_model.pose_keys(p, t, fps, h, inner_keys, task.body.joints)
            poses.append(p[::stride])
            ik.append(inner_keys[::stride])
            ok.append(keys[::stride])
            th.append(np.full(len(p[::stride]), h))
    return np.concatenate(poses), np.concatenate(ik), np.concatenate(ok), np.concatenate(th)


def extended(rig: Rig, extra: int) -> Rig:
    """`rig` with `extra` zero blend shapes after its own (driven by keys appended to the rig's own)."""
    zeros = np.zeros((extra,) + rig.blend_shapes.shape[1:], np.float32)
    return Rig(rig.weights, np.concatenate([rig.blend_shapes, zeros]))


def fitted_rigs(task: layers_outer.OuterTask, outer_rig: Rig, frames, gain: float,
                extra: np.ndarray | None = None) -> tuple[Rig, Rig, float]:
    """Both rigs refit to their posed vertices moved `gain` times toward the post step between layers at the fit
    frames -> (inner rig, outer rig, seconds). extra (T, E): more keys at the fit frames (e.g. DeePSD's pose keys),
    each driving a corrective blend shape of its own (zero before the fit) in both rigs."""
    t0 = time.perf_counter()
    poses, ik, ok, th = frames
    joints = task.body.joints
    inner = pose_outfit(task.inner_vertices, task.inner_model.rig, ik, joints, poses)
    outer = pose_outfit(task.vertices, outer_rig, ok, joints, poses)
    inner_rig = task.inner_model.rig
    if extra is not None:  # the extra shapes start at zero: the posed layers above are those of the extended rigs
        ik, ok = np.concatenate([ik, extra], 1), np.concatenate([ok, extra], 1)
        inner_rig, outer_rig = extended(inner_rig, extra.shape[1]), extended(outer_rig, extra.shape[1])
    bodies = task.body.pose(poses)
    ri, ro = np.empty_like(inner), np.empty_like(outer)
    refiners: dict[float, LayerRefiner] = {}
    for i in range(len(poses)):
        h = float(th[i])
        if h not in refiners:
            refiners[h] = LayerRefiner(task.inner_faces, len(task.inner_vertices), task.faces, len(task.vertices),
                                       h, task.body.faces, len(task.body.vertices))
        ri[i], ro[i] = refiners[h].refine_frame(inner[i], outer[i], bodies[i], None)
    g = np.float32(gain)
    return (sparse_rig(task.inner_vertices, inner_rig, joints, 4, poses, ik, targets=inner + g * (ri - inner)),
            sparse_rig(task.vertices, outer_rig, joints, 4, poses, ok, targets=outer + g * (ro - outer)),
            time.perf_counter() - t0)


def measure_variant(task: layers_outer.OuterTask, model: OuterModel, icfg: dict, ir: Rig, orig: Rig, base_seqs: list,
                    base_clips: list, extra_keys) -> tuple[dict, dict, int]:
    """One variant's rigs on both validation splits -> (inner figures, outer figures, validation sequences)."""
    def keyed(poses: np.ndarray, keys: np.ndarray, rig: Rig) -> np.ndarray:  # the extra keys, where fitted
        return keys if len(rig.blend_shapes) == keys.shape[1] else np.concatenate([keys, extra_keys(poses)], 1)

    def inner_pose(poses: np.ndarray, trans: np.ndarray) -> np.ndarray:
        keys = keyed(poses, task.inner_model.pose_keys(poses), ir)
        return pose_outfit(task.inner_vertices, ir, keys, task.body.joints, poses, trans)

    def pose(s) -> np.ndarray:
        keys = keyed(s.poses, model.keys_of_features(s.features, s.thickness, s.inner_keys), orig)
        return pose_outfit(task.vertices, orig, keys, task.body.joints, s.poses, s.trans)

    inner_fig = layers_inner.measure(icfg, task.inner_vertices, task.inner_faces, task.body, inner_pose)
    seqs, clips = ([replace(q, inner=inner_pose(q.poses, q.trans)) for q in base] for base in (base_seqs, base_clips))
    outer_fig = (layers_outer.measure_all(task, seqs, clips, pose) if seqs else
                 {"rmse_mm": float("nan"), "l_coll_pct": float("nan"), "h_coll_pct": float("nan"),
                  "sted": float("nan")} | layers_outer.measure_clips(task, clips, pose))
    return inner_fig, outer_fig, len(seqs)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gains", default="1,3")
    ap.add_argument("--stride", type=int, default=6)
    ap.add_argument("--thickness", default="0.004,0.008,0.012")
    ap.add_argument("--pairs", default=",".join(f"{i}_{o}" for i, o in PAIRS))
    ap.add_argument("--out", default="")
    ap.add_argument("--ridge", default="")
    ap.add_argument("--pose-keys", default="", help="deepsd: corrective shapes driven by DeePSD's pose keys too")
    ap.add_argument("--real", type=int, default=0, help="frames of each real training clip among the fit frames")
    ap.add_argument("--inner-only", action="store_true",
                    help="also each gain with only the inner rig fitted (the outer rig as shipped)")
    args = ap.parse_args()
    if args.ridge:
        from drape.runtime import sparse_rig as sr

        sr.RIDGE = float(args.ridge)

    results = {}
    for inner_name, outer_name in PAIRS:
        if f"{inner_name}_{outer_name}" not in args.pairs.split(","):
            continue
        cfg = layers_outer.load_config(outer_name)
        task = layers_outer.OuterTask(cfg)
        model = OuterModel(OUTER_MODELS / f"{inner_name}_{outer_name}")
        icfg = layers_inner.load_config(inner_name)
        shipped_inner = task.inner_model.rig
        frames = fit_frames(task, model, [float(x) for x in args.thickness.split(",")], args.stride, args.real)
        print(f"{inner_name}+{outer_name}: {len(frames[0])} fit frames", flush=True)
        extra_keys = None
        if args.pose_keys == "deepsd":
            from drape.runtime.deepsd import DeePSDModel

            extra_keys = DeePSDModel().pose_keys
        extra = None if extra_keys is None else extra_keys(frames[0])
        variants: dict[str, tuple[Rig, Rig]] = {"none": (shipped_inner, model.rig)}
        for g in [float(x) for x in args.gains.split(",")]:
            ir, orig, s = fitted_rigs(task, model.rig, frames, g, extra)
            print(f"  gain {g}: fit {s:.1f} s", flush=True)
            variants[f"gain{g:g}"] = (ir, orig)
            if args.inner_only:  # the inner rig fitted as `drape train mgn-inner-fit` fits it, the outer as shipped
                from drape.training.layers_inner_fit import fit_inner_rig, fit_poses

                inner = task.inner_model
                served = fit_inner_rig(task.inner_vertices, task.inner_faces, inner.rig, inner.pose_keys, task.body,
                                       fit_poses(args.stride), g)
                variants[f"gain{g:g}_inner"] = (served, model.rig)
        # the validation sequences and clips, prepared with the shipped inner rig (their inner keys are the inner
        # network's, which the outer network reads); each variant re-poses their inner layer with its own rig
        base_seqs = task.sequences("test") if (task.data_dir / "manifest.json").exists() else []
        base_clips = layers_outer.validation_clips(task)
        for name, (ir, orig) in variants.items():
            inner_fig, outer_fig, n = measure_variant(task, model, icfg, ir, orig, base_seqs, base_clips, extra_keys)
            results[f"{inner_name}+{outer_name}/{name}"] = {"inner": inner_fig, "outer": outer_fig}
            print(f"  {name:8} inner: inside {inner_fig['inside_triangle_pct']:.2f}% edge "
                  f"{inner_fig['edge_error_mm']:.2f} mm score {inner_fig['score']:.2f} | outer ({n} seqs): "
                  f"RMSE {outer_fig['rmse_mm']:.1f} mm L-Coll {outer_fig['l_coll_pct']:.2f}% H-Coll "
                  f"{outer_fig['h_coll_pct']:.2f}% STED {outer_fig['sted']:.3f} | real clips L-Coll "
                  f"{outer_fig.get('clip_l_coll_pct', float('nan')):.2f}% H-Coll "
                  f"{outer_fig.get('clip_h_coll_pct', float('nan')):.2f}%", flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
