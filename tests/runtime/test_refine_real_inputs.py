"""Issue 20's refinement bar on real inputs: the real ArcSim tops of ../shared/data/external, fitted onto the neutral
body, rigged by the served DeePSD rig and animated along real CMU mocap (fairmotion 01_01 and the held-out
05_02_dance, 30 fps, every 12th frame), refined as animate refines them (`Engine.pose_chunks(refine=...)`: the
edge-limit pass with the outfit's rest shape, the last check, FAR_K): no vertex inside the body on any frame (exact
closest-triangle sign, independent of the refiner's own query) and no edge made longer than 2x its rest length that
was not that long before refinement. Before the last check and FAR_K were on, 1-3 vertices (0.23-0.91%) stayed inside
on the worst frames at the armpits (docs/refine.md). bench/refine_edges measures the same rows and more.
"""

from pathlib import Path

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import import_motion
from drape.geometry.fitting import fit_garment
from drape.geometry.mesh import unique_edges
from drape.geometry.mesh_io import load_mesh
from drape.geometry.queries import signed_distance_to_mesh
from drape.runtime.engine import Engine, RefineSettings

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
GARMENTS = sorted((SHARED / "external").glob("*.obj")) if (SHARED / "external").is_dir() else []
CLIPS = [SHARED / "external" / "fairmotion_01_01.bvh", SHARED / "mocap" / "05_02_dance.bvh"]
needs_data = pytest.mark.skipif(len(GARMENTS) < 2 or not all(c.exists() for c in CLIPS),
                                reason=f"the real garments and clips are not in {SHARED} (outside the repository)")


@pytest.fixture(scope="module")
def engine():
    e = Engine(refine_workers=1)
    yield e
    e.close()


@needs_data
@pytest.mark.parametrize("path", GARMENTS, ids=lambda p: p.stem)
def test_animate_refined_on_real_tops_and_real_mocap_leaves_nothing_inside(engine, path):
    body = load_body("neutral")
    v, f = load_mesh(path)
    fit = fit_garment(v, f, body)
    outfit = engine.rig(fit.vertices, f, "neutral")
    edges = unique_edges(outfit.faces)
    rest = np.linalg.norm(outfit.vertices[edges[:, 0]] - outfit.vertices[edges[:, 1]], axis=1)
    for clip in CLIPS:
        motion = import_motion(clip.read_bytes(), body, fps=30.0, name=clip.stem).motion
        poses, trans = motion.poses.reshape(-1, 24, 3)[::12], motion.trans[::12]
        raw = np.concatenate(list(engine.pose_chunks(outfit, poses, trans)))
        refined = np.concatenate(list(engine.pose_chunks(outfit, poses, trans, refine=RefineSettings())))
        posed = body.pose(poses, trans).astype(np.float64)
        inside = [int(np.sum(signed_distance_to_mesh(r.astype(np.float64), b, body.faces) < 0))
                  for r, b in zip(refined, posed, strict=True)]
        assert max(inside) == 0, (clip.stem, inside)
        before = np.linalg.norm(raw[:, edges[:, 0]] - raw[:, edges[:, 1]], axis=2) / rest
        after = np.linalg.norm(refined[:, edges[:, 0]] - refined[:, edges[:, 1]], axis=2) / rest
        assert not np.any((after > 2.0) & (before <= 2.0)), clip.stem
        # the premise: the unrefined stream has the body through it
        assert max(np.mean(signed_distance_to_mesh(r.astype(np.float64), b, body.faces) < 0)
                   for r, b in zip(raw, posed, strict=True)) > 0.02
