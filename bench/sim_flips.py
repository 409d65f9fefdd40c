"""Do the real CMU dances the intrinsic skirt's quality gate rejected pass it once their rotation flips are repaired?

Each clip of --clips (../shared/data/mocap) is imported at 30 fps with and without the importer's flip repair
(drape.assets.motion_flips; `drape motions import --keep-flips` is the unrepaired one) and simulated with the
skirt of `make intrinsic-data` (DIR/skirt.obj) for the dataset's frames under each parameter set of --params
(indices into the dataset manifest's sets). Prints the flipped spans inside the simulated frames, the gate's
body-penetration figures (p99 and max, mm; bars 5 and 30 mm), the share of vertex-frames inside the body, the
verdict, the frames on which a thigh pierces the skirt (the hip -> knee segment of either leg crosses a cloth
triangle: the leg went through the cloth, which then cuts across it; the dropped dances' deep penetration sits
on exactly such frames) and the wall time. Needs the dataset's folder (git-ignored; `make intrinsic-data` makes its manifest
and skirt.obj first).
Run: .venv/bin/python -m bench.sim_flips [--dataset data/intrinsic/skirt] [--clips 05_10_dance,...] [--params 0,1]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import import_motion
from drape.geometry.mesh_io import load_mesh
from drape.geometry.skeleton import JOINT_INDEX, forward_kinematics
from drape.sim.params import SimParams
from drape.sim.quality import QualityGate
from drape.sim.simulate import simulate

THIGHS = [(JOINT_INDEX["left_hip"], JOINT_INDEX["left_knee"]), (JOINT_INDEX["right_hip"], JOINT_INDEX["right_knee"])]


def segment_crosses(a: np.ndarray, b: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Does the segment a -> b (3,) cross any triangle of the mesh (vertices (N, 3), faces (F, 3))? Moller-Trumbore."""
    v0, v1, v2 = (vertices[faces[:, k]].astype(np.float64) for k in range(3))
    d, e1, e2 = b - a, v1 - v0, v2 - v0
    h = np.cross(d, e2)
    det = np.einsum("fc,fc->f", e1, h)
    ok = np.abs(det) > 1e-12
    inv = 1.0 / np.where(ok, det, 1.0)
    s = a - v0
    u = inv * np.einsum("fc,fc->f", s, h)
    q = np.cross(s, e1)
    v = inv * (q @ d)
    t = inv * np.einsum("fc,fc->f", e2, q)
    return bool((ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)).any())


def pierced_frames(cloth: np.ndarray, faces: np.ndarray, joints: np.ndarray) -> int:
    """cloth (T, N, 3), posed joints (T, 24, 3) -> frames on which a thigh's hip -> knee segment crosses the cloth."""
    return sum(any(segment_crosses(joints[t, h], joints[t, k], cloth[t], faces) for h, k in THIGHS)
               for t in range(len(cloth)))

# the dances `make intrinsic-data-motions` dropped (docs/intrinsic.md, "Version 0.3.0") that hold flips
DEFAULT_CLIPS = "05_10_dance,05_19_dance,05_15_dance,05_14_dance"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="data/intrinsic/skirt")
    parser.add_argument("--mocap", default="../shared/data/mocap")
    parser.add_argument("--clips", default=DEFAULT_CLIPS)
    parser.add_argument("--params", default="0,1")
    args = parser.parse_args()
    root = Path(args.dataset)
    manifest = json.loads((root / "manifest.json").read_text())
    gate = QualityGate(**manifest["gate"])
    body = load_body(manifest["body"])
    vertices, faces = load_mesh(root / "skirt.obj")
    frames = int(manifest["frames"])
    print("clip  set  repaired  flipped spans in the frames  p99 mm  max mm  inside %  gate  pierced frames  s")
    for clip in args.clips.split(","):
        data = (Path(args.mocap) / f"{clip}.bvh").read_bytes()
        for p in map(int, args.params.split(",")):
            for repair in (True, False):
                imported = import_motion(data, body, fps=30.0, flips=repair, name=clip)
                source_fps = imported.source_fps
                inside = [f.describe() for f in imported.flips if f.first < frames * source_fps / 30.0]
                t0 = time.perf_counter()
                r = simulate(vertices, faces, body, imported.motion, SimParams(**manifest["params"][p]), frames=frames)
                s = r.stats
                fails = gate.failures(s)
                m = imported.motion
                _, joints = forward_kinematics(m.poses[:frames], body.joints, body.parents, m.trans[:frames])
                pierced = pierced_frames(r.vertices, faces, joints)
                print(f"{clip}  {p}  {'yes' if repair else 'no'}  {'; '.join(inside) or '-'}  "
                      f"{1e3 * s['penetration_p99_m']:.1f}  {1e3 * s['penetration_max_m']:.1f}  "
                      f"{100 * s['inside_share']:.2f}  {'pass' if not fails else 'reject'}  "
                      f"{pierced}  {time.perf_counter() - t0:.0f}", flush=True)


if __name__ == "__main__":
    main()
