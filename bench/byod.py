"""Bring your own data, end to end through the client against a live service (the README's walk-through):
a real CMU mocap file, a garment made for no body of ours, and a user's own body.

1. Body: the `heavy` preset scaled by 1.05 (a body none of the presets is), written as a skinned GLB whose
   joints carry SMPL-FBX-style names ("m_avg_L_Hip", ...), registered with `Client.register_body`.
2. Motion: ../shared/data/external/fairmotion_01_01.bvh (CMU 01_01, 120 fps), sent as a file: the service
   retargets it onto the outfit's body at 30 fps. The same import is run here (`import_motion`, what
   `drape motions import` runs) to measure against: frames, the median lowest-body-point height (mm).
3. Garment: ../shared/data/external/ncsim_arcsim_tshirtw.obj (ArcSim, unknown units and placement), fitted
   onto the body with `Client.fit` (units and up inferred): its report.
4. Rig (`Client.rig`) and animate the fitted garment on the BVH file (`Client.animate(motion=Path(...))`), without
   and with `refine`: per frame (every 4th is measured), the
   share of garment vertices inside the posed body (exact signed distance to its triangles; median and
   largest over frames), the largest edge length over its rest length, the edges refinement made longer than
   2x their rest length that were not that long unrefined (count over the measured frame-edges), and the wall
   time of each call.

Run: .venv/bin/python -m bench.byod [CLIP.bvh]  (about 3 minutes on the 2-core machine). The default clip, CMU 01_01,
is also ../shared/data/mocap/01_01_jump.bvh, a training clip of the one-command configs (deepsd_wide.json and
later; not of the shipped 0.6.0); pass a clip every config holds out (../shared/data/mocap/02_01_walk.bvh,
05_02_dance.bvh, 06_02_sports.bvh) to see a motion no model saw.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

import drape
from bench.http import loopback_server
from drape.assets.body import Body, load_body
from drape.assets.motion import import_motion
from drape.geometry.queries import signed_distance_to_mesh
from drape.geometry.skeleton import JOINT_NAMES
from drape.schemas.gltf import Skeleton, SkinnedMesh, skinned_glb

EXTERNAL = Path("..") / "shared" / "data" / "external"
BVH = EXTERNAL / "fairmotion_01_01.bvh"
GARMENT = EXTERNAL / "ncsim_arcsim_tshirtw.obj"
SCALE = 1.05
EVERY = 4


def fbx_name(smpl: str) -> str:
    """'left_hip' -> 'm_avg_L_Hip': the naming of SMPL's own FBX files."""
    side, _, rest = smpl.partition("_")
    if side in ("left", "right"):
        return f"m_avg_{side[0].upper()}_{rest.capitalize()}"
    return f"m_avg_{smpl.capitalize()}"


def user_body_glb() -> bytes:
    heavy = load_body("heavy")
    skeleton = Skeleton(tuple(fbx_name(n) for n in JOINT_NAMES), heavy.parents, heavy.joints * SCALE)
    return skinned_glb(skeleton, [SkinnedMesh("body", heavy.vertices * SCALE, heavy.faces, heavy.weights)])


def inside_shares(frames: np.ndarray, body: Body, poses: np.ndarray, trans: np.ndarray) -> np.ndarray:
    posed = body.pose(poses, trans)
    return np.array([(signed_distance_to_mesh(f.astype(np.float64), b.astype(np.float64), body.faces) < 0).mean()
                     for f, b in zip(frames, posed, strict=True)])


def edge_stretch(frames: np.ndarray, rest: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Each edge's length over its rest length per frame: frames (T, N, 3), rest (N, 3) -> (T, E)."""
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    rest_len = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    return np.linalg.norm(frames[:, edges[:, 0]] - frames[:, edges[:, 1]], axis=2) / np.maximum(rest_len, 1e-9)


def main(bvh: Path = BVH) -> None:
    if not bvh.exists() or not GARMENT.exists():
        sys.exit(f"needs {bvh} and {GARMENT} (../shared/data)")
    print(f"clip: {bvh}")
    with loopback_server() as url, drape.Client(url, timeout=600) as client:
        t = time.perf_counter()
        reg = client.register_body(user_body_glb())
        print(f"body: {reg.body_id}, {reg.num_vertices} vertices, {reg.height:.3f} m tall "
              f"(register {time.perf_counter() - t:.2f} s)")
        arrays = client.body(reg.body_id)
        body = Body(reg.body_id, arrays.vertices, arrays.faces, arrays.weights, arrays.joints, arrays.parents,
                    tuple(arrays.joint_names))

        t = time.perf_counter()
        motion = import_motion(bvh.read_bytes(), body, fps=30.0, name=bvh.stem)
        clip = motion.motion
        poses, trans = clip.poses[::EVERY].astype(np.float64), clip.trans[::EVERY].astype(np.float64)
        lowest = body.pose(clip.poses, clip.trans)[:, :, 1].min(axis=1)
        print(f"motion: {clip.num_frames} frames at {clip.fps:g} fps (import {time.perf_counter() - t:.2f} s); "
              f"median lowest body point {np.median(lowest) * 1000:.1f} mm; using every {EVERY}th frame: "
              f"{len(poses)}")

        t = time.perf_counter()
        fit = client.fit(GARMENT, body=reg.body_id)
        r = fit.report
        print(f"fit: units {r['units']} (inferred {r['units_inferred']}), up {r['up']} (inferred "
              f"{r['up_inferred']}); inside at rest {r['inside_before']:.1%} -> {r['inside_after']:.2%}; moves mean "
              f"{r['mean_move_mm']:.1f} / max {r['max_move_mm']:.1f} mm, max stretch {r['max_stretch_mm']:.1f} mm "
              f"({time.perf_counter() - t:.2f} s)")

        rig = client.rig((fit.vertices, fit.faces), body=reg.body_id)
        warnings = rig.diagnostics.get("warnings", [])
        print(f"rig: inside at rest {rig.diagnostics['inside_share']:.2%}; warnings: {warnings or 'none'}")
        print(f"{'':10} {'inside median':>14} {'inside max':>11} {'stretch max':>12} {'new >2x':>8} {'s':>6}")
        unrefined = None
        for refine in (False, True):
            t = time.perf_counter()
            frames = client.animate(outfit_id=rig.outfit_id, motion=bvh, refine=refine)
            seconds = time.perf_counter() - t
            assert len(frames) == clip.num_frames, (len(frames), clip.num_frames)
            frames = frames[::EVERY]
            shares = inside_shares(frames, body, poses, trans)
            stretch = edge_stretch(frames, fit.vertices, fit.faces)
            new_long = "" if unrefined is None else str(int(np.count_nonzero((stretch > 2) & (unrefined <= 2))))
            unrefined = stretch if unrefined is None else unrefined
            print(f"{'refined' if refine else 'unrefined':10} {np.median(shares):14.2%} {shares.max():11.2%} "
                  f"{stretch.max():11.2f}x {new_long:>8} {seconds:6.1f}")
        client.delete_body(reg.body_id)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else BVH)
