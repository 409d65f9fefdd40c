"""Training frames of the intrinsic garment space from a simulated dataset (`drape sim dataset`).

Per accepted item (one parameter set x one motion): the garment's vertices and the body's joint
positions, both moved into the character space of each frame (`character_space_numpy`), and each
frame's motion window: the joint positions of that frame and the W before it (the first frame
repeated before the sequence starts), all in that frame's character space.

Arrays of a `Frames` set: vertices (F, N, 3) float32 m, windows (F, W + 1, 24, 3) float32 m,
params (F,) int (the parameter-set index), motions (F,) int (index into `motion_names`),
frame (F,) int (the frame within its sequence).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.geometry.character_space import character_space_numpy, motion_windows, root_frames


@dataclass
class Frames:
    vertices: np.ndarray
    windows: np.ndarray
    params: np.ndarray
    motions: np.ndarray
    frame: np.ndarray
    motion_names: list[str]

    def __len__(self) -> int:
        return len(self.vertices)

    def subset(self, mask: np.ndarray) -> Frames:
        return Frames(self.vertices[mask], self.windows[mask], self.params[mask], self.motions[mask],
                      self.frame[mask], self.motion_names)


def load_frames(dataset: str | Path | Sequence[str | Path], window: int, splits: tuple[str, ...] = ("train",),
                garment: str | None = None) -> tuple[Frames, np.ndarray, dict]:
    """Every accepted item of the given splits -> (Frames, faces (F, 3) int32, the first dataset's manifest).

    dataset: one dataset folder, or several simulated for the same template on the same body with the same
    parameter sampler (`--params`, `--seed`: a parameter-set index means the same cloth in each; checked), e.g.
    more training motions simulated into a folder of their own."""
    roots = [Path(dataset)] if isinstance(dataset, (str, Path)) else [Path(d) for d in dataset]
    for r in roots:
        if not (r / "manifest.json").is_file():
            raise FileNotFoundError(f"{r}: no simulated dataset here (no manifest.json); the Makefile's "
                                    "intrinsic-data targets simulate each one (docs/intrinsic.md names which)")
    manifests = [json.loads((r / "manifest.json").read_text()) for r in roots]
    for r, m in zip(roots[1:], manifests[1:], strict=True):
        for key in ("body", "params", "garments", "frames"):
            if m.get(key) != manifests[0].get(key):
                raise ValueError(f"{r}: its {key!r} differs from {roots[0]}'s; datasets read together must be "
                                 "simulated with the same template, body, frames and parameter sampler")
    body = load_body(manifests[0]["body"])
    items = [(r, it) for r, m in zip(roots, manifests, strict=True) for it in m["items"] if it["split"] in splits
             and (garment is None or it["garment"] == garment)]
    if not items:
        raise ValueError(f"{', '.join(map(str, roots))}: no accepted items in splits {splits}")
    # each folder splits by its own --holdout-* and motion list: a training item of one must not be a parameter
    # set or motion another holds out (the test split shares neither with training)
    held_params = {p for m in manifests for p in m.get("splits", {}).get("test_params", [])}
    held_motions = {x for m in manifests for x in m.get("splits", {}).get("test_motions", [])}
    for root, it in items:
        if it["split"] == "train" and (it["params"] in held_params or it["motion"] in held_motions):
            raise ValueError(f"{root / it['file']}: a training item of a parameter set or motion that a dataset read "
                             f"with it holds out (test_params {sorted(held_params)}, test_motions "
                             f"{sorted(held_motions)}); simulate the folders with the same --holdout-* and held-out "
                             "motions")
    names = sorted({it["motion"] for _, it in items})
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("vertices", "windows", "params", "motions", "frame")}
    faces = None
    for root, it in items:
        with np.load(root / it["file"], allow_pickle=False) as z:
            verts, poses, trans = z["vertices"], z["poses"].astype(np.float64), z["trans"].astype(np.float64)
            faces = z["faces"] if faces is None else faces
        joints, rp, rr = root_frames(poses, trans, body.joints, body.parents)
        parts["vertices"].append(character_space_numpy(verts.astype(np.float64), rp, rr).astype(np.float32))
        parts["windows"].append(motion_windows(joints, rp, rr, window))
        parts["params"].append(np.full(len(verts), it["params"]))
        parts["motions"].append(np.full(len(verts), names.index(it["motion"])))
        parts["frame"].append(np.arange(len(verts)))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    frames = Frames(cat["vertices"], cat["windows"], cat["params"], cat["motions"], cat["frame"], names)
    assert faces is not None
    return frames, np.asarray(faces, np.int32), manifests[0]
