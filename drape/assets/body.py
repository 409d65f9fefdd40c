"""The embedded body presets (baked from anny by `drape assets bake-body`), and the user bodies registered
in this process (`register_body`; the service's body store registers what `POST /v1/bodies` accepts).

Files: drape/assets/bodies/<preset>.npz (full body) and <preset>_proxy.npz
(~1.2k-vertex collision proxy, same skeleton) with arrays
vertices (V, 3) float32 m, faces (F, 3) int32, weights (V, 24) float32,
joints (24, 3) float32 m (rest joints), parents (24,) int32, joint_names (24,) str.
Rest pose: T-pose, +Y up, facing +Z, feet on y = 0.
"""

from __future__ import annotations

import threading
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


@lru_cache(maxsize=1)
def _preset_names() -> tuple[str, ...]:
    return tuple(sorted(p.stem for p in BODIES_DIR.glob("*.npz") if not p.stem.endswith("_proxy")))


def list_bodies() -> list[str]:
    """Names of the embedded presets (the proxies are not listed separately)."""
    return list(_preset_names())


# user bodies registered in this process: name -> (body, registrations); names are content hashes
# (drape.runtime.body_store), so two registrations of one name hold the same arrays
_registered: dict[str, tuple[Body, int]] = {}
_registry_lock = threading.Lock()


def register_body(body: Body) -> None:
    """Make a user body loadable by its name (`load_body`) until as many `unregister_body` calls."""
    if body.name in _preset_names():
        raise ValueError(f"{body.name!r} is a preset's name")
    with _registry_lock:
        count = _registered.get(body.name, (body, 0))[1]
        _registered[body.name] = (body, count + 1)


def unregister_body(name: str) -> None:
    with _registry_lock:
        body, count = _registered.get(name, (None, 0))
        if body is None:
            return
        if count > 1:
            _registered[name] = (body, count - 1)
        else:
            del _registered[name]


def is_registered(name: str) -> bool:
    """True for a user body registered in this process (not for presets)."""
    return name in _registered


def has_body(name: str) -> bool:
    """True for an embedded preset or a user body registered in this process: a name load_body finds."""
    return name in _preset_names() or is_registered(name)


def load_body(name: str = "neutral", proxy: bool = False) -> Body:
    """A preset or a registered user body (KeyError if neither); proxy=True gives a preset's
    low-resolution collision proxy (a user body is its own proxy)."""
    user = _registered.get(name)
    if user is not None:
        return user[0]
    return _load_preset(name, proxy)


@lru_cache(maxsize=16)
def _load_preset(name: str, proxy: bool) -> Body:
    if name not in _preset_names():
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
