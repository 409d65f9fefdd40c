"""Does refinement tear garments? New long edges and what is left inside, per refinement variant.

Inputs (the issue's bar: real garments, real mocap, and generated outfits):
- the real ArcSim tops of ../shared/data/external, fitted onto the neutral body (drape.geometry.fitting),
  animated by the served DeePSD rig (4 influences) along real CMU clips drape never trained on
  (fairmotion 01_01 and the eval's REAL_CLIPS, imported at 30 fps), every EVERY-th frame;
- a generated 6k-vertex long sleeve + trousers on the held-out clip dance_b (bench/refine_spikes' case).

Per variant, over all frames: the share of vertices inside the body after refinement (median and worst
frame, by an exact signed distance independent of the refiner's own query), the edges made longer than
2x their rest length that were not already that long in the input (count over all frame-edges, how many
of them pass through the body: ends on opposite sides of a limb, bench/refine_spikes.passes_through; and
the worst such edge's length over its rest length), the largest stretch against rest of any edge, and the
refinement's milliseconds per frame in this process. Variants: `relief` (what /v1/refine runs: it has no rest
shape), `edges 1.5x` (what animate runs: the edge-limit pass, `Refiner(rest=...)`, edges capped at max(ratio x rest,
input length)), each with the refinement's defaults (the last check over 8 nearest body vertices on what lies within
1 cm, the surface's FAR_K) and without the last check (-chk); `before`: the relief pass without the check on a
surface without FAR_K, what both routes ran before them.

Run: .venv/bin/python -m bench.refine_edges [--every 6] [--far-k 0] [--stream-rest] [--model-dir DIR] [--stretch-iterations 15,30]
[--stretch-extra 0,15] [--animate-only] (about 5 minutes on the 2-core
machine; --stream-rest adds two variants with a rest guessed from the stream, for /v1/refine without a rest shape:
docs/refine.md, section "`/v1/refine` without a rest shape")
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench.refine_spikes import passes_through
from drape.assets.body import Body, load_body
from drape.assets.motion import import_motion, load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.fitting import fit_garment
from drape.geometry.mesh import unique_edges
from drape.geometry.mesh_io import load_mesh
from drape.geometry.queries import signed_distance_to_mesh
from drape.geometry.refine import (
    FAR_K,
    STRETCH_EXTRA,
    STRETCH_EXTRA_OMEGA,
    STRETCH_ITERATIONS,
    BodySurface,
    Refiner,
    RefineReport,
)
from drape.runtime.engine import Engine
from drape.training.deepsd_eval import REAL_CLIPS

SHARED = Path("..") / "shared" / "data"
LONG = 2.0  # the bar: no edge made longer than 2x its rest length


def motions(body, clips=None):  # noqa: ANN001, ANN201
    """[(name, poses (T, 24, 3), translation (T, 3))]: real CMU clips at 30 fps (those present): fairmotion 01_01
    and REAL_CLIPS, or the named clips of ../shared/data/mocap."""
    paths = ([SHARED / "external" / "fairmotion_01_01.bvh", *(SHARED / "mocap" / f"{c}.bvh" for c in REAL_CLIPS)]
             if clips is None else [SHARED / "mocap" / f"{c}.bvh" for c in clips])
    out = []
    for p in paths:
        if p.exists():
            m = import_motion(p.read_bytes(), body, fps=30.0, name=p.stem).motion
            out.append((p.stem, m.poses.reshape(-1, 24, 3), m.trans))
    return out


def cases(every: int, clips=None):  # noqa: ANN001, ANN201
    """[(garment name, rest vertices (N, 3), faces, [(clip, poses, translation)])]; clips: as `motions`."""
    body = load_body("neutral")
    real = [(n, p[::every], t[::every]) for n, p, t in motions(body, clips)]
    out = []
    for path in sorted((SHARED / "external").glob("*.obj")):
        v, f = load_mesh(path)
        fit = fit_garment(v, f, body)
        out.append((path.stem, fit.vertices, f, real))
    o = generate_outfit("longsleeve,trousers", vertices=6000, seed=77)
    clip = load_clip("dance_b")
    out.append(("longsleeve,trousers 6k", o.vertices, o.faces,
                [("dance_b", clip.poses.reshape(-1, 24, 3)[::every // 2 or 1], clip.trans[::every // 2 or 1])]))
    return out


def setup(ap: argparse.ArgumentParser) -> tuple[argparse.Namespace, Engine, Body, BodySurface]:
    """`--far-k` added to the bench's arguments, parsed -> (args, the engine, the neutral body, its surface)."""
    ap.add_argument("--far-k", type=int, default=FAR_K,
                    help="BodySurface(far_k=...): points read outside that one of that many nearest vertices reads "
                         "inside are asked again over their faces "
                         f"(0: not; the refinement's surfaces: {FAR_K})")
    ap.add_argument("--model-dir", default=None, help="a DeePSD export to rig with (default: the served one)")
    args = ap.parse_args()
    body = load_body("neutral")
    engine = Engine(refine_workers=1) if args.model_dir is None else Engine(args.model_dir, refine_workers=1)
    return args, engine, body, BodySurface(body.faces, len(body.vertices), far_k=args.far_k or None)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--every", type=int, default=6, help="use every k-th frame of the real clips")
    ap.add_argument("--ratios", default="1.5", help="edge-limit caps to try, times the rest length")
    ap.add_argument("--clips", default=None,
                    help="comma-separated clips of ../shared/data/mocap instead of fairmotion 01_01 and REAL_CLIPS "
                         "(e.g. the validation clips 05_04_dance,06_01_walk,06_03_sports)")
    ap.add_argument("--stream-rest", action="store_true",
                    help="also the edge-limit pass with a rest guessed from the stream (no rest shape given): each "
                         "edge's median length over the frames (`stream median`), or the frame closest to those "
                         "medians (`stream frame`)")
    ap.add_argument("--stretch-iterations", default=str(STRETCH_ITERATIONS),
                    help="comma-separated rounds of the edge-limit pass to try (Refiner(stretch_iterations=...)); "
                         f"variants other than the refinement's {STRETCH_ITERATIONS} are named `edges RATIOx itN`")
    ap.add_argument("--stretch-extra", default=str(STRETCH_EXTRA),
                    help="comma-separated Refiner(stretch_extra=...) to try: edge-limit rounds spent only while a new "
                         f"edge over 2x rest shrinks; variants other than the refinement's {STRETCH_EXTRA} are named "
                         "`edges RATIOx +N`")
    ap.add_argument("--stretch-extra-omega", default=str(STRETCH_EXTRA_OMEGA),
                    help="comma-separated Refiner(stretch_extra_omega=...) to try: the extra rounds' step; variants "
                         f"other than the refinement's {STRETCH_EXTRA_OMEGA} are named `edges RATIOx wW`")
    ap.add_argument("--animate-only", action="store_true", help="only the edge-limit variants (what animate runs)")
    args, engine, body, surface = setup(ap)
    # what both routes ran before the last check and FAR_K were on: the relief pass, the plain surface
    plain = BodySurface(body.faces, len(body.vertices))
    print(f"{'garment':24s} {'clip':14s} {'N':>5s} {'T':>4s} {'variant':18s} {'inside med':>10s} {'worst':>6s} "
          f"{'new >2x':>7s} {'through':>7s} {'worst new':>9s} {'max/rest':>8s} {'ms/frame':>8s}")
    for name, rest, faces, clips in cases(args.every, args.clips.split(",") if args.clips else None):
        out = engine.rig(rest, faces, "neutral")
        edges = unique_edges(out.faces)
        rest_len = np.linalg.norm(out.vertices[edges[:, 0]] - out.vertices[edges[:, 1]], axis=1)
        variants = {} if args.animate_only else {
            "before": (Refiner(out.faces, len(rest), verify_k=0), plain),
            "relief -chk": (Refiner(out.faces, len(rest), verify_k=0), surface),
            "relief": (Refiner(out.faces, len(rest)), surface)}
        for r in args.ratios.split(","):
            if not args.animate_only:
                variants[f"edges {r}x -chk"] = (Refiner(out.faces, len(rest), rest=out.vertices,
                                                        stretch_ratio=float(r), verify_k=0), surface)
            for n in (int(k) for k in args.stretch_iterations.split(",")):
                for extra in (int(k) for k in args.stretch_extra.split(",")):
                    for w in (float(k) for k in args.stretch_extra_omega.split(",")):
                        if extra == 0 and w != STRETCH_EXTRA_OMEGA:
                            continue  # no extra rounds: their step does not matter
                        label = (f"edges {r}x" + ("" if n == STRETCH_ITERATIONS else f" it{n}")
                                 + ("" if extra == STRETCH_EXTRA else f" +{extra}")
                                 + ("" if w == STRETCH_EXTRA_OMEGA else f" w{w:g}"))
                        variants[label] = (Refiner(out.faces, len(rest), rest=out.vertices, stretch_ratio=float(r),
                                                   stretch_iterations=n, stretch_extra=extra, stretch_extra_omega=w),
                                           surface)
        for clip, poses, trans in clips:
            frames = np.concatenate(list(engine.pose_chunks(out, poses, trans))).astype(np.float64)
            bodies = body.pose(poses, trans).astype(np.float64)
            lengths = np.linalg.norm(frames[:, edges[:, 0]] - frames[:, edges[:, 1]], axis=2)  # (T, E) m
            before = lengths / rest_len
            clip_variants = dict(variants)
            if args.stream_rest:  # no rest shape given: one guessed from the stream itself
                median = np.median(lengths, axis=0)
                k = int(np.argmin(np.abs(lengths - median).sum(axis=1)))
                clip_variants["stream median"] = (Refiner(out.faces, len(rest), rest_length=median), surface)
                clip_variants["stream frame"] = (Refiner(out.faces, len(rest), rest=frames[k]), surface)
            inside0 = [np.mean(signed_distance_to_mesh(f, b, body.faces) < 0) for f, b in zip(frames, bodies, strict=True)]
            print(f"{name[:24]:24s} {clip:14s} {len(rest):5d} {len(frames):4d} {'input':18s} "
                  f"{np.median(inside0):10.2%} {max(inside0):6.2%} {'':7s} {'':7s} {'':9s} {before.max():7.2f}x")
            for label, (refiner, collider) in clip_variants.items():
                t = time.perf_counter()
                refined = np.stack([refiner.refine_frame(f, b, collider, RefineReport())
                                    for f, b in zip(frames, bodies, strict=True)])
                ms = 1e3 * (time.perf_counter() - t) / len(frames)
                after = np.linalg.norm(refined[:, edges[:, 0]] - refined[:, edges[:, 1]], axis=2) / rest_len
                new = (after > LONG) & (before <= LONG)
                worst_new = after[before <= LONG].max()
                through = sum(int(passes_through(refined[i][edges[e, :1]], refined[i][edges[e, 1:]], bodies[i],
                                                 body.faces)[0]) for i, e in zip(*np.nonzero(new), strict=True))
                inside = [np.mean(signed_distance_to_mesh(f, b, body.faces) < 0)
                          for f, b in zip(refined, bodies, strict=True)]
                print(f"{'':24s} {'':14s} {'':5s} {'':4s} {label:18s} {np.median(inside):10.2%} {max(inside):6.2%} "
                      f"{int(new.sum()):7d} {through:7d} {worst_new:8.2f}x {after.max():7.2f}x {ms:8.1f}", flush=True)


if __name__ == "__main__":
    main()
