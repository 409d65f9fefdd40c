"""Does the outer network's training body term see the cloth that the evaluation counts inside the body?

H-Coll (drape eval layers, layers_outer's validation) counts an outer vertex inside the body by the exact closest
triangle of the full body mesh. The training's body term reads `physics.BodyCollider` instead: the nearest posed
body vertex among candidates (the vertex's nearest body vertices at rest, plus the neighbourhood of its nearest
posed proxy vertex) and that vertex's normal. Where the two disagree, the body term gives no push to cloth that
is counted inside. For an exported outer network (`--shipped`, as the runtime poses it) along the config's real
validation clips (`mocap.validation`; no held-out motion), per clip: the share of vertex-frames inside by the exact
measure; of those, the shares the collider puts inside (sd < 0) and within the body term's margin (sd < eps_body);
their depth (exact, mm: median and 90th percentile); and the body joints they lie at (the joint that skins the
closest body vertex most). Two colliders: the tangent plane of the nearest body vertex (what the served networks
trained with) and the closest point on the triangles around it (`triangles`).
Run: PYTHONPATH=. .venv/bin/python -m bench.layers_collider_agreement --config drape/training/configs/X.json
     --shipped drape/assets/models/mgn_outer/<inner>_<outer>   (a few minutes on the 2-core machine)
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from bench.layers_outer_runs import pose_shipped
from drape.assets.body import load_body
from drape.geometry.queries import signed_distance_to_mesh
from drape.geometry.skeleton import JOINT_NAMES
from drape.runtime.layers import OuterModel
from drape.training import layers_outer, physics
from drape.training.config_file import read_config


def agreement(task: layers_outer.OuterTask, collider: physics.BodyCollider, seq: layers_outer.Sequence, v: np.ndarray,
              eps_body: float) -> dict:
    """v (T, No, 3) m posed along seq -> the figures of the module's docstring for that clip, by `collider`."""
    bodies = task.body.pose(seq.poses, seq.trans).astype(np.float64)
    exact = np.stack([signed_distance_to_mesh(x, b, task.body.faces) for x, b in zip(v, bodies, strict=True)])
    with torch.no_grad():
        transforms = physics.skinning_transforms(torch.as_tensor(seq.poses), task.joints)
        trained = collider.signed_distance(torch.as_tensor(v - seq.trans[:, None], dtype=torch.float32),
                                           transforms).numpy()
    inside = exact < 0
    joints: Counter = Counter()
    for t in np.flatnonzero(inside.any(1)):
        _, nearest = cKDTree(bodies[t]).query(v[t, inside[t]])
        joints.update(JOINT_NAMES[j] for j in task.body.weights[nearest].argmax(1))
    n = max(int(inside.sum()), 1)
    depth = -exact[inside] * 1e3 if inside.any() else np.zeros(1)
    return {"inside_pct": 100 * float(inside.mean()),
            "collider_inside_pct_of_those": 100 * float((trained[inside] < 0).sum()) / n,
            "collider_within_margin_pct_of_those": 100 * float((trained[inside] < eps_body).sum()) / n,
            "collider_inside_pct": 100 * float((trained < 0).mean()),
            "depth_mm_median": float(np.median(depth)), "depth_mm_p90": float(np.percentile(depth, 90)),
            "joints": {k: round(100 * c / n, 1) for k, c in joints.most_common(4)}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", required=True)
    parser.add_argument("--shipped", type=Path, required=True, help="an exported outer network's folder")
    args = parser.parse_args()
    cfg = read_config(args.config, "mgn_outer")
    task = layers_outer.OuterTask(cfg)
    net = OuterModel(args.shipped)
    eps_body = float({**cfg["loss"], **cfg.get("mocap", {}).get("loss", {})}["eps_body"])
    print(f"{args.shipped}: inside = exact closest triangle; of those, the training collider's sd < 0 and "
          f"< eps_body {eps_body * 1e3:.0f} mm")
    colliders = {name: physics.BodyCollider(task.body, load_body(cfg["body"], proxy=True), task.vertices,
                                            triangles=name == "triangles") for name in ("vertex plane", "triangles")}
    for seq in layers_outer.validation_clips(task):
        v = pose_shipped(net, task, seq)
        for name, collider in colliders.items():
            f = agreement(task, collider, seq, v, eps_body)
            print(f"{seq.motion:14} {name:12} inside {f['inside_pct']:.2f}% (collider alone "
                  f"{f['collider_inside_pct']:.2f}%); of those the collider: inside "
                  f"{f['collider_inside_pct_of_those']:.0f}%, within the margin "
                  f"{f['collider_within_margin_pct_of_those']:.0f}%; depth {f['depth_mm_median']:.1f} mm median, "
                  f"{f['depth_mm_p90']:.1f} p90; at {f['joints']}", flush=True)


if __name__ == "__main__":
    main()
