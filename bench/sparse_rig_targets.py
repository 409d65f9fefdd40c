"""Can the served rig's blend-shape refit buy back the quality that pruning to 4 influences costs? A
validation study: the refit's targets relaxed towards rest edge lengths and out of the body.

drape.runtime.sparse_rig fits the 4-influence rig's blend shapes to the dense rig's posed vertices at 300
fit poses (frames of the clips DeePSD trained on). Here the targets are relaxed first (`relaxed_targets`:
Jacobi position-based rounds moving each edge towards its rest length, then every vertex within eps of the
body, or inside, put on its closest body point + eps), so that the refit bends the 4-influence rig towards
a cloth that stretches less and stays outside. Variants: served (the dense rig's vertices as targets, what is
served), edge10 (10 relaxation rounds, no push), edge10push (10 rounds then one push at the end),
edge10push5 (a push every 5 rounds).

Validation only (never the held-out table of `drape eval deepsd`): the eval's 11 outfit types with other
seeds (80000 + i) on the next body in turn, along two procedural motions (seeds 7001, 7002) and three real
CMU clips used nowhere else (05_04_dance, 06_03_sports, 06_01_walk from ../shared/data/mocap, 30 fps), 12
evenly spaced frames each. Prints per outfit and as means: vertices inside the body (closest triangle, %),
edge error (mm), and the seconds each fit takes, with the ratios to `served`.
Run: .venv/bin/python -m bench.sparse_rig_targets [--outfits tshirt,jacket]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from drape.assets.body import load_body
from drape.assets.motion import import_motion
from drape.assets.procedural import generate_motion
from drape.geometry.mesh import unique_edges, vertex_normals
from drape.geometry.metrics import edge_length_error_mm
from drape.geometry.queries import MeshDistance
from drape.geometry.refine import BodySurface
from drape.runtime.deepsd import DeePSDModel, pose_outfit
from drape.runtime.sparse_rig import fit_poses, sparse_rig
from drape.training import DEFAULT_DEEPSD_CONFIG
from drape.training.deepsd_data import OutfitSpec, load_outfit

CMU = ("05_04_dance", "06_03_sports", "06_01_walk")
MOCAP = Path("..") / "shared" / "data" / "mocap"
VARIANTS = {"edge10": {"push_every": None}, "edge10push": {"push_every": 10}, "edge10push5": {"push_every": 5}}


def relaxed_targets(posed: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray, body_posed: np.ndarray,
                    body_faces: np.ndarray, iterations: int = 10, eps: float = 0.003,
                    push_every: int | None = 5) -> np.ndarray:
    """posed (T, N, 3) m (the dense rig at the fit poses), body_posed (T, M, 3) m -> (T, N, 3) float32 m: each
    round moves every edge's ends towards its rest length (averaged over a vertex's edges); every `push_every`
    rounds (None: never) vertices within eps of the body go to their closest body point + eps."""
    T, N = posed.shape[:2]
    e = unique_edges(np.asarray(faces))
    E = len(e)
    rest = np.asarray(rest_vertices, dtype=np.float64)
    length = np.linalg.norm(rest[e[:, 1]] - rest[e[:, 0]], axis=1)[:, None]
    diff = sp.csr_matrix((np.r_[np.ones(E), -np.ones(E)], (np.r_[np.arange(E), np.arange(E)],
                                                             np.r_[e[:, 1], e[:, 0]])), shape=(E, N))
    spread = sp.csr_matrix(diff.T.multiply(1.0 / np.maximum(np.bincount(e.ravel(), minlength=N), 1)[:, None]))
    x = np.ascontiguousarray(np.asarray(posed, dtype=np.float64).transpose(1, 0, 2)).reshape(N, 3 * T)
    surface = BodySurface(body_faces, body_posed.shape[1])
    for it in range(iterations):
        d = (diff @ x).reshape(E, T, 3)
        stretch = 1.0 - length / np.maximum(np.linalg.norm(d, axis=2), 1e-12)
        x -= spread @ (0.5 * stretch[..., None] * d).reshape(E, 3 * T)
        if push_every and (it + 1) % push_every == 0:
            xt = x.reshape(N, T, 3)
            for t in range(T):
                b = np.asarray(body_posed[t], dtype=np.float64)
                sd, cp, n = surface.query(b, surface.normals(b), xt[:, t])
                near = sd < eps
                xt[near, t] = cp[near] + eps * n[near]
    return np.ascontiguousarray(x.reshape(N, T, 3).transpose(1, 0, 2), dtype=np.float32)


def quality(model: DeePSDModel, verts: np.ndarray, faces: np.ndarray, body, rigs: dict, motions: list) -> dict:  # noqa: ANN001
    """{variant: (inside %, edge error mm)} over 12 frames of each motion."""
    inside: dict[str, list[float]] = {m: [] for m in rigs}
    edge: dict[str, list[float]] = {m: [] for m in rigs}
    for motion in motions:
        fr = np.linspace(0, motion.num_frames - 1, 12).round().astype(int)
        poses, trans = motion.poses[fr].astype(np.float64), motion.trans[fr].astype(np.float64)
        keys = model.pose_keys(poses)
        posed = {m: pose_outfit(verts, r, keys, body.joints, poses, trans) for m, r in rigs.items()}
        bodies = body.pose(poses, trans)
        for t in range(len(fr)):
            b = bodies[t].astype(np.float64)
            dist = MeshDistance(b, body.faces, vertex_normals(b, body.faces))
            for m in rigs:
                inside[m].append(float(np.mean(dist.signed_distance(posed[m][t].astype(np.float64)) < 0)))
        for m in rigs:
            edge[m].append(edge_length_error_mm(posed[m], verts, faces))
    return {m: (100 * float(np.mean(inside[m])), float(np.mean(edge[m]))) for m in rigs}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--outfits", default=None, help="comma list of outfit types (default: the eval's 11)")
    args = p.parse_args()
    cfg = json.loads(Path(DEFAULT_DEEPSD_CONFIG).read_text())
    model = DeePSDModel()
    fit = fit_poses()
    fit_keys = model.pose_keys(fit)
    bodies = cfg["bodies"]
    names = ["model", "served", *VARIANTS]
    table: dict[str, dict] = {}
    seconds: dict[str, list[float]] = {m: [] for m in names}
    print("validation: inside the body (closest triangle, %) / edge error (mm) / fit seconds")
    for i, kind in enumerate(cfg["eval_outfits"]):
        if args.outfits and kind not in args.outfits.split(","):
            continue
        spec = OutfitSpec(kind, cfg["eval_vertices"], 80000 + i, bodies[(i + 1) % len(bodies)])
        verts, faces = load_outfit(spec)
        body = load_body(spec.body)
        motions = [generate_motion(300, seed=7000 + j, body=body) for j in (1, 2)]
        motions += [import_motion((MOCAP / f"{c}.bvh").read_bytes(), body, fps=30.0, name=c).motion for c in CMU]
        dense = model.rig(verts, faces, body)
        rigs = {"model": dense}
        t0 = time.perf_counter()
        rigs["served"] = sparse_rig(verts, dense, body.joints, 4, fit, fit_keys)
        seconds["served"].append(time.perf_counter() - t0)
        for name, kw in VARIANTS.items():
            t0 = time.perf_counter()
            posed = pose_outfit(verts, dense, fit_keys, body.joints, fit)
            targets = relaxed_targets(posed, verts, faces, body.pose(fit), body.faces, **kw)
            rigs[name] = sparse_rig(verts, dense, body.joints, 4, fit, fit_keys, targets=targets)
            seconds[name].append(time.perf_counter() - t0)
        table[kind] = quality(model, verts, faces, body, rigs, motions)
        print(f"{kind:18s} " + " | ".join(f"{m} {a:.2f}% {e:.2f}mm" for m, (a, e) in table[kind].items()), flush=True)
    print("\nmeans over outfits (ratio to served):")
    s_in = np.mean([table[o]["served"][0] for o in table])
    s_edge = np.mean([table[o]["served"][1] for o in table])
    for m in names:
        a = np.mean([table[o][m][0] for o in table])
        e = np.mean([table[o][m][1] for o in table])
        worst = max(table[o][m][1] for o in table)
        sec = f"{np.mean(seconds[m]):.1f} s" if seconds[m] else "-"
        print(f"  {m:12s} inside {a:.2f}% ({a / s_in:.2f}x)  edge {e:.3f} mm ({e / s_edge:.3f}x, worst outfit "
              f"{worst:.2f})  fit {sec}")


if __name__ == "__main__":
    main()
