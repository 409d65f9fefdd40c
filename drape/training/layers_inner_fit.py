"""The inner-layer network's rig refit to keep the inner garment out of the body (`drape train mgn-inner-fit`).

MGN's inner-layer network ends in a linear rig (skin weights + a basis driven by the network's 64 keys,
drape.runtime.layers.InnerModel), so the served DeePSD rig's collision fit applies to it alone: at fit frames
(every `stride`-th frame of the embedded clips DeePSD and the layer networks trained on,
drape.runtime.sparse_rig.FIT_CLIPS, of three procedural training motions, seeds 501-503, and of the first
`real_frames` frames of each real CMU clip the network trained on; never a validation or evaluation motion), pose the inner layer, refine each frame out of the body by the post step's inner pass
(drape.geometry.layers.inner_refiner), and refit the rig (at most 4 influences a vertex,
drape.runtime.sparse_rig.sparse_rig) to the posed layer moved `gain` times toward that result. The network
(pose.onnx) does not change, so the outer-layer network trained beside it still serves (it reads the network's
keys, not the inner vertices).

The fit serves only where it measures better: the inner network's validation split (drape.training.layers_inner:
inside % + edge error mm) before and after, the lower score kept; both are in the manifest's `collision_fit`.
Configured by the inner config's `"collision_fit": {"gain": g, "stride": s, "real_frames": r}` (r 0 or absent:
no real clips); `drape train mgn-inner` runs it after
the export, `drape train mgn-inner-fit` on a network already exported (once: a fitted rig is not fitted again, nor measured twice).
Shapes: template vertices (N, 3) m; poses (T, 24, 3) rad; keys (T, K).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from drape.assets.body import Body, load_body
from drape.assets.motion import load_clip
from drape.assets.procedural import generate_motion
from drape.runtime.collision_fit import PROCEDURAL_SEEDS
from drape.runtime.deepsd import Rig, pose_outfit
from drape.runtime.sparse_rig import FIT_CLIPS, sparse_rig

PROCEDURAL_FRAMES = 300  # PROCEDURAL_SEEDS: those of the served DeePSD rig's collision fit, 501-503
INFLUENCES = 4


def fit_poses(stride: int, real: list[np.ndarray] | None = None) -> np.ndarray:
    """(T, 24, 3) float32 rad: every `stride`-th frame of the embedded FIT_CLIPS, of the procedural motions
    (PROCEDURAL_SEEDS, PROCEDURAL_FRAMES frames each) and of `real` (poses (T_i, 24, 3) rad each), in that
    order."""
    motions = [load_clip(name).poses for name in FIT_CLIPS]
    motions += [generate_motion(PROCEDURAL_FRAMES, seed=s).poses for s in PROCEDURAL_SEEDS]
    motions += list(real or [])
    return np.concatenate([np.asarray(p, np.float32)[::stride] for p in motions])


def real_fit_motions(cfg: dict, frames: int) -> list[np.ndarray]:
    """The first `frames` frames of each real CMU clip the inner network trained on (the config's mocap.train,
    read as its training's pose pool reads them: deepsd_data.mocap_poses) -> [poses (T_i, 24, 3) float32 rad];
    none for 0."""
    from drape.training.deepsd_data import mocap_poses, repairs_flips

    mocap = cfg["mocap"]
    if frames <= 0:
        return []
    return [mocap_poses(mocap["dir"], name, mocap["fps"], flips=repairs_flips(mocap))[:frames]
            for name in mocap["train"]]


def fit_inner_rig(vertices: np.ndarray, faces: np.ndarray, rig: Rig, pose_keys: Callable[[np.ndarray], np.ndarray],
                  body: Body, poses: np.ndarray, gain: float) -> Rig:
    """The inner layer's rig (template vertices (N, 3) m, faces (F, 3)) refit to its posed vertices at `poses`
    (T, 24, 3) rad moved `gain` times toward the post step's inner pass (out of the body) -> Rig (at most 4
    influences a vertex). pose_keys: poses (T, 24, 3) -> the network's keys (T, K)."""
    from drape.geometry.layers import inner_refiner
    from drape.geometry.refine import FAR_K, BodySurface, RefineReport

    keys = pose_keys(poses)
    posed = pose_outfit(vertices, rig, keys, body.joints, poses)
    bodies = body.pose(poses).astype(np.float64)
    refiner, surface = inner_refiner(faces, len(vertices)), BodySurface(body.faces, len(body.vertices), far_k=FAR_K)
    refined = np.stack([refiner.refine_frame(posed[t].astype(np.float64), bodies[t], surface, RefineReport())
                        for t in range(len(poses))])
    targets = (posed + gain * (refined - posed)).astype(np.float32)
    return sparse_rig(vertices, rig, body.joints, INFLUENCES, poses, keys, targets=targets)


def apply(folder: str | Path, cfg: dict, log: Callable[[str], object] = print) -> dict:
    """Fit the rig of the inner network exported in `folder` (drape.export.layers.export_inner) by `cfg`'s
    `collision_fit`, measure both rigs on `cfg`'s validation split, and keep the lower score: rig.npz and the
    manifest (its sha256 and `collision_fit`: settings, both figures, `served` "fitted" or "network") rewritten.
    -> the manifest's `collision_fit`. A ValueError for a folder whose fit was measured already."""
    from drape.export.onnx_export import sha256
    from drape.runtime.layers import InnerModel
    from drape.training.layers_inner import measure

    folder = Path(folder)
    model = InnerModel(folder, threads=2)
    if "collision_fit" in model.manifest:
        raise ValueError(f"{folder}: the rig's collision fit was measured already (serving the "
                         f"{model.manifest['collision_fit']['served']} rig); export the network again to redo it")
    settings = cfg["collision_fit"]
    body = load_body(cfg["body"])
    poses = fit_poses(int(settings["stride"]), real_fit_motions(cfg, int(settings.get("real_frames", 0))))
    fitted = fit_inner_rig(model.vertices, model.faces, model.rig, model.pose_keys, body, poses,
                           float(settings["gain"]))

    def figures(rig: Rig) -> dict:
        return measure(cfg, model.vertices, model.faces, body,
                       lambda p, t: pose_outfit(model.vertices, rig, model.pose_keys(p), body.joints, p, t))

    before, after = figures(model.rig), figures(fitted)
    served = "fitted" if after["score"] < before["score"] else "network"
    log(f"validation score: network's rig {before['score']:.3f}, fitted {after['score']:.3f} -> serving {served}")
    record = {"settings": settings, "fit_frames": len(poses), "validation_network": before,
              "validation_fitted": after, "served": served}
    manifest = model.manifest
    if served == "fitted":
        rig_path = folder / manifest["files"]["rig"]["file"]
        np.savez(rig_path, vertices=model.vertices, faces=model.faces, weights=fitted.weights.astype(np.float32),
                 blend_shapes=fitted.blend_shapes.astype(np.float32))
        manifest["files"]["rig"].update(sha256=sha256(rig_path), bytes=rig_path.stat().st_size)
    manifest["collision_fit"] = record
    manifest["config"]["collision_fit"] = settings  # the recipe: the training, then this fit
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return record
