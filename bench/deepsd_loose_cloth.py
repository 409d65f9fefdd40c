"""Where does DeePSD stretch a long dress? Per-vertex edge error of the held-out dress of `drape eval deepsd`
(dress, 3,000 vertices, seed 90006, neutral body) along the held-out clips (12 frames each), for the shipped
model and, with --compare DIR, another export in the same run (e.g. 0.6.0's files from git).

Prints per clip and model: the mean edge-length error (mm, over edges and frames), the worst 10% of vertices
(a vertex's error: the mean over its edges), the share of them below the knee joint's height and within 6 cm of
the body's mid-plane (between the legs), and, for a model with candidate joints, the joints those vertices may
use (drape.geometry.queries.candidate_joints), and the mean rig weight on the pelvis of those vertices and of every
vertex beyond 3 cm of the body (loose_points).
Run: .venv/bin/python -m bench.deepsd_loose_cloth [--compare DIR]
"""

from __future__ import annotations

import argparse

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.geometry.mesh import unique_edges
from drape.geometry.queries import candidate_joints, loose_points
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, pose_outfit
from drape.training.deepsd_data import OutfitSpec, load_outfit

CLIPS = ("walk", "kick", "dance_b")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--compare", help="another DeePSD export folder, measured beside the shipped one")
    args = parser.parse_args()
    v, f = load_outfit(OutfitSpec("dress", 3000, 90006, "neutral"))
    body = load_body("neutral")
    names = body.joint_names
    e = unique_edges(f)
    rest = np.linalg.norm(v[e[:, 1]] - v[e[:, 0]], axis=1)
    knee_y = body.joints[names.index("left_knee"), 1]
    loose = loose_points(v, body.vertices, 0.03)  # (N,) bool: beyond 0.9.0's and 0.10.0's loose_beyond
    print(f"dress {len(v)} vertices, y {v[:, 1].min():.2f}-{v[:, 1].max():.2f} m; knee joint y {knee_y:.2f} m")
    models = {"shipped": DeePSDModel(MODEL_DIR)}
    if args.compare:
        models["compare"] = DeePSDModel(args.compare)
    for clip in CLIPS:
        m = load_clip(clip)
        fr = np.linspace(0, m.num_frames - 1, 12).round().astype(int)
        p, t = m.poses[fr].astype(np.float64), m.trans[fr].astype(np.float64)
        for label, model in models.items():
            rig = model.rig(v, f, body)
            g = pose_outfit(v, rig, model.pose_keys(p), body.joints, p, t)
            err = np.abs(np.linalg.norm(g[:, e[:, 1]] - g[:, e[:, 0]], axis=2) - rest).mean(axis=0) * 1e3  # (E,) mm
            per_vertex = np.zeros(len(v))
            np.add.at(per_vertex, e[:, 0], err)
            np.add.at(per_vertex, e[:, 1], err)
            per_vertex /= np.maximum(np.bincount(e.ravel(), minlength=len(v)), 1)
            worst = np.argsort(-per_vertex)[: len(v) // 10]
            line = (f"{clip:8s} {label} {model.manifest['version']}: edge error {err.mean():.2f} mm; worst 10% of "
                    f"vertices {per_vertex[worst].mean():.1f} mm, {100 * np.mean(v[worst, 1] < knee_y):.0f}% below the "
                    f"knee, {100 * np.mean(np.abs(v[worst, 0]) < 0.06):.0f}% within 6 cm of the mid-plane, their "
                    f"pelvis weight {rig.weights[worst, names.index('pelvis')].mean():.3f} (loose cloth's "
                    f"{rig.weights[loose, names.index('pelvis')].mean():.3f})")
            if model.joint_candidates is not None:
                mask = candidate_joints(v[worst], body.vertices, body.weights, parents=body.parents,
                                        **model.joint_candidates)
                counts = mask.sum(axis=0)
                top = np.argsort(-counts)[:6]
                line += "; their candidates: " + ", ".join(f"{names[j]} {counts[j]}" for j in top if counts[j])
            print(line)


if __name__ == "__main__":
    main()
