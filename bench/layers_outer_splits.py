"""The served outer-layer network on its own training and validation sequences (drape.training.layers_outer).

Poses the shipped outer network (ONNX Runtime, as served) along every sequence of `make layers-data` that its
config trains on and along the validation sequences, and prints outer RMSE (mm, against the simulation), L-Coll
(% outer vertices behind the *served* inner network's layer, as the network's validation rule and `drape eval
layers` judge it), H-Coll (% inside the body, exact closest triangle) and STED per split, and L-Coll per training motion; and the simulated jacket itself judged the
same way (against the served inner layer, not the simulated one). It tells whether a high L-Coll on held-out
motions is the motions' (low on the training sequences) or the fit's (high there too), and how far the target
the vertex loss pulls towards already lies behind the inner layer the network is judged against.

Run: .venv/bin/python -m bench.layers_outer_splits [--outer jacket]   (about half an hour on 2 cores: the exact
H-Coll of every training frame; needs data/layers)
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np

from drape.runtime.deepsd import pose_outfit
from drape.runtime.layers import load_outer_model
from drape.training.layers_outer import OuterTask, Sequence, load_config, measure_sequences


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--outer", default="jacket")
    args = ap.parse_args()
    cfg = load_config(args.outer)
    task = OuterTask(cfg)
    net = load_outer_model(cfg["inner"], cfg["outer"])
    if net is None:
        raise SystemExit(f"no shipped outer network for {cfg['pair']}")

    def pose(s: Sequence) -> np.ndarray:
        keys = net.pose_keys(s.poses, s.trans, 30.0, s.thickness, s.inner_keys, task.body.joints)
        return pose_outfit(task.vertices, net.rig, keys, task.body.joints, s.poses, s.trans)

    train = [s for s in task.sequences("train") if s.key in set(cfg["train_items"])]
    print(f"{cfg['pair']}: the served outer network (L-Coll against the served inner network's layer)")
    print("| split | sequences | outer RMSE mm | L-Coll % | H-Coll % | STED |\n| --- | --: | --: | --: | --: | --: |")
    per_motion: dict[str, list[float]] = defaultdict(list)
    for name, seqs in (("train", train), ("validation", task.sequences("test"))):
        r = measure_sequences(task, seqs, pose)
        print(f"| {name} | {len(seqs)} | {r['rmse_mm']:.1f} | {r['l_coll_pct']:.2f} | {r['h_coll_pct']:.2f} | "
              f"{r['sted']:.3f} |")
        t = measure_sequences(task, seqs, lambda s: s.outer)
        print(f"| {name}: the simulated outer | {len(seqs)} | 0 | {t['l_coll_pct']:.2f} | {t['h_coll_pct']:.2f} | 0 |")
        if name == "train":
            for s in seqs:
                per_motion[s.motion].append(r["sequences"][s.key]["l_coll_pct"])
    print("L-Coll % per training motion: " + ", ".join(f"{m} {np.mean(v):.2f}" for m, v in sorted(per_motion.items())))


if __name__ == "__main__":
    main()
