"""What animate's refinement leaves inside the body on the real tops, vertex by vertex.

The inputs of bench/refine_edges (the real ArcSim tops of ../shared/data/external fitted onto the neutral body,
posed by the served DeePSD rig along real CMU clips at 30 fps, every EVERY-th frame), refined as `animate` refines
(`Refiner(rest=...)`, the edge-limit pass, stretch_ratio 1.5). For every vertex still inside the posed body after
refinement (exact closest-triangle sign), one line per frame: its depth (mm, negative inside) by the exact sign,
by the refiner's own query (`BodySurface.query`, faces around the 2 nearest body vertices) and by the last
check's (8 nearest), the generalised winding number (1: inside one body part, 2: where two overlap), the joint
that skins its nearest body vertex most, and its depth in the input (before refinement). Then a count of those
vertices the refiner's own query calls outside, and how far.

Run: .venv/bin/python -m bench.refine_left_inside [--every 12]  (about 1 minute on the 2-core machine)
"""

from __future__ import annotations

import argparse

import numpy as np

from bench.refine_edges import cases, setup
from drape.geometry.queries import signed_distance_to_mesh, winding_number
from drape.geometry.refine import Refiner, RefineReport, body_tree
from drape.geometry.skeleton import JOINT_NAMES


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--every", type=int, default=12, help="use every k-th frame of the real clips")
    args, engine, body, surface = setup(ap)
    missed: list[float] = []  # the refiner's own depth reading (mm) of every vertex left inside
    total = 0
    for name, rest, faces, clips in cases(args.every):
        if len(rest) > 2000:  # the generated 6k outfit: bench/refine_edges has it
            continue
        out = engine.rig(rest, faces, "neutral")
        refiner = Refiner(out.faces, len(rest), rest=out.vertices, stretch_ratio=1.5)
        for clip, poses, trans in clips:
            frames = np.concatenate(list(engine.pose_chunks(out, poses, trans))).astype(np.float64)
            bodies = body.pose(poses, trans).astype(np.float64)
            for t, (f, b) in enumerate(zip(frames, bodies, strict=True)):
                r = refiner.refine_frame(f, b, surface, RefineReport())
                sd = signed_distance_to_mesh(r, b, body.faces)
                bad = np.nonzero(sd < 0)[0]
                if len(bad) == 0:
                    continue
                normals, tree = surface.normals(b), body_tree(b)
                own = surface.query(b, normals, r[bad], tree)[0]
                check = surface.query(b, normals, r[bad], tree, k=8)[0]
                wn = winding_number(r[bad], b, body.faces)
                joint = [JOINT_NAMES[j] for j in body.weights[tree.query(r[bad])[1]].argmax(1)]
                before = signed_distance_to_mesh(f[bad], b, body.faces)
                total += len(bad)
                missed += [1e3 * s for s in own if s >= 0]
                for i in range(len(bad)):
                    print(f"{name[:24]:24s} {clip:17s} frame {t:3d} vertex {bad[i]:4d}: exact {1e3 * sd[bad[i]]:6.1f} "
                          f"own {1e3 * own[i]:6.1f} check {1e3 * check[i]:6.1f} mm, winding {wn[i]:.2f}, "
                          f"{joint[i]}, input {1e3 * before[i]:6.1f} mm")
    if total:
        print(f"{total} vertex-frames left inside; the refiner's own query calls {len(missed)} of them outside "
              f"(median {np.median(missed) if missed else 0:.1f} mm, largest {max(missed, default=0):.1f} mm)")


if __name__ == "__main__":
    main()
