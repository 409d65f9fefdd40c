"""Are a DeePSD model's blend weights on the body's joints, or do its blend shapes carry the cloth instead?

For each model folder given (default: the shipped one), on the held-out jacket of `drape eval deepsd` (3,000
vertices, seed 90007, female body) along the held-out clip dance_b (every 10th frame):
- the joints that carry the left sleeve (vertices with x > 0.3 m and y > 1.2 m in the T-pose rest): the count
  of vertices per largest-weight joint, against the nearest body vertex's weights (the prior);
- how far the posed garment lies from where its own weights alone put it (LBS without the blend shapes), per
  vertex and frame: the share over 10 cm and the 95th percentile (mm);
- weights_off_prior (drape.training.deepsd_validation): vertices whose largest weight is not among the nearest
  body vertex's two largest joints (%).

Run: .venv/bin/python -m bench.deepsd_weights [MODEL_DIR ...]
(e.g. the reverted 0.7.0: `git show ccc74f8:drape/assets/models/deepsd/<file>` for its three files)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.geometry.lbs import pose_mesh
from drape.geometry.queries import nearest_vertex_weights
from drape.geometry.skeleton import JOINT_NAMES
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, pose_outfit
from drape.training.deepsd_data import OutfitSpec, load_outfit
from drape.training.deepsd_validation import weights_off_prior


def main(model_dirs: list[Path]) -> None:
    spec = OutfitSpec("jacket", 3000, 90007, "female")
    body = load_body(spec.body)
    v, f = load_outfit(spec)
    sleeve = (v[:, 0] > 0.3) & (v[:, 1] > 1.2)
    prior = nearest_vertex_weights(v, body.vertices, body.weights)
    clip = load_clip("dance_b")
    poses, trans = clip.poses[::10].astype(np.float64), clip.trans[::10].astype(np.float64)

    def joints(w: np.ndarray) -> str:
        names, counts = np.unique(w[sleeve].argmax(axis=1), return_counts=True)
        return ", ".join(f"{JOINT_NAMES[j]} {c}" for j, c in sorted(zip(names, counts, strict=True), key=lambda x: -x[1]))

    print(f"{spec.key}: {len(v)} vertices, left sleeve {int(sleeve.sum())}; dance_b, {len(poses)} frames")
    print(f"  prior (nearest body vertex): {joints(prior)}")
    for d in model_dirs:
        model = DeePSDModel(d)
        rig = model.rig(v, f, body)
        posed = pose_outfit(v, rig, model.pose_keys(poses), body.joints, poses, trans)
        own = pose_mesh(v, rig.weights, body.joints, poses, trans)
        away = np.linalg.norm(posed - own, axis=-1)  # (T, N) m
        print(f"{d}: sleeve on {joints(rig.weights)}; blend shapes move {100 * np.mean(away > 0.1):.1f}% of "
              f"vertex-frames > 10 cm from the own-weights pose (p95 {1000 * np.percentile(away, 95):.0f} mm); "
              f"weights off prior {weights_off_prior(rig.weights, prior):.1f}%")


if __name__ == "__main__":
    main([Path(a) for a in sys.argv[1:]] or [MODEL_DIR])
