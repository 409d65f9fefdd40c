"""How each way DeePSD reads a garment changes bench.byod's case: the ArcSim t-shirt of ../shared/data/external
(426 vertices, 67 mm mean edges) fitted onto bench.byod's user body (the `heavy` preset x 1.05, 2.05 m: outside the
trained heights), posed along a CMU clip (every 4th frame) by the dense rig of the shipped weights read as they
are (`scale_bodies=None, densify_edge=None`), scaled into the trained heights, scaled and subdivided (the service's default), and that with
each vertex's answer averaged over its finer one-ring (`densify_ring`); beside the nearest-body-weights baseline. Prints the share of the shirt's vertices inside
the body (median frame; exact closest-triangle signed distance), the largest edge length over its rest length,
and the share of edge-frames over 2x.

Run: .venv/bin/python -m bench.byod_reading [CLIP.bvh]  (default ../shared/data/mocap/02_01_walk.bvh, held out
of every config; about a minute).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from bench.byod import GARMENT, SCALE
from drape.assets.body import Body, load_body
from drape.assets.motion import import_motion
from drape.geometry.fitting import fit_garment
from drape.geometry.lbs import pose_mesh
from drape.geometry.mesh import unique_edges
from drape.geometry.mesh_io import load_mesh
from drape.geometry.queries import nearest_vertex_weights, signed_distance_to_mesh
from drape.runtime.deepsd import DeePSDModel, pose_outfit

CLIP = Path("..") / "shared" / "data" / "mocap" / "02_01_walk.bvh"


def main(clip_path: Path = CLIP) -> None:
    if not clip_path.exists() or not GARMENT.exists():
        sys.exit(f"needs {clip_path} and {GARMENT} (../shared/data)")
    heavy = load_body("heavy")
    body = Body("user", heavy.vertices * SCALE, heavy.faces, heavy.weights, heavy.joints * SCALE, heavy.parents,
                heavy.joint_names)
    v0, f0 = load_mesh(GARMENT)
    verts, faces = fit_garment(v0, f0, body).vertices.astype(np.float32), f0
    e = unique_edges(faces)
    rest = np.linalg.norm(verts[e[:, 0]] - verts[e[:, 1]], axis=1)
    clip = import_motion(clip_path.read_bytes(), body, fps=30.0, name=clip_path.stem).motion
    poses, trans = clip.poses[::4].astype(np.float64), clip.trans[::4].astype(np.float64)
    posed_body = body.pose(poses, trans)
    print(f"{clip_path.stem}: {len(poses)} frames; shirt {len(verts)} vertices, edges {rest.mean() * 1e3:.0f} mm "
          f"(mean); body {np.ptp(body.vertices[:, 1]):.2f} m")
    frames = {"baseline": pose_mesh(verts, nearest_vertex_weights(verts, body.vertices, body.weights), body.joints,
                                    poses, trans)}
    readings = {"as it is": DeePSDModel(scale_bodies=None, densify_edge=None),
                "scaled": DeePSDModel(densify_edge=None), "scaled + subdivided (served)": DeePSDModel(),
                "+ ring": DeePSDModel(densify_ring=True)}
    for name, model in readings.items():
        frames[name] = pose_outfit(verts, model.rig(verts, faces, body), model.pose_keys(poses), body.joints, poses,
                                   trans)
    for name, fr in frames.items():
        inside = [np.mean(signed_distance_to_mesh(g.astype(np.float64), b.astype(np.float64), body.faces) < 0)
                  for g, b in zip(fr, posed_body, strict=True)]
        ratio = np.linalg.norm(fr[:, e[:, 0]] - fr[:, e[:, 1]], axis=2) / rest
        print(f"{name:20} inside {np.median(inside):6.2%}  largest edge {ratio.max():5.2f}x  "
              f"edge-frames over 2x {np.mean(ratio > 2):.3%}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else CLIP)
