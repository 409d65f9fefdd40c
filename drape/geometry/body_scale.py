"""A body a network never saw, brought into the range of body heights it was trained on.

DeePSD's outfit network reads each garment vertex's rest position in metres (`drape.runtime.deepsd.
network_inputs`), so what it predicts depends on where the garment is, not only on its shape: trained on
bodies 1.66-1.80 m tall, it sees a 2 m body's shoulder line where it learned necks. `BodyScale` is the
uniform scaling about the floor point under the pelvis that makes a body's height the nearest height of
the trained range (the identity for a body inside it): the network reads the garment scaled by it, and
the blend shapes it answers (displacements, metres) are scaled back by its inverse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def body_height(vertices: np.ndarray) -> float:
    """vertices (V, 3) m, Y-up, rest pose -> height (m): the extent along Y."""
    y = np.asarray(vertices, dtype=np.float64)[:, 1]
    return float(y.max() - y.min())


@dataclass(frozen=True)
class BodyScale:
    """p -> pivot + scale * (p - pivot). scale: dimensionless; pivot (3,) float64 m."""

    scale: float
    pivot: np.ndarray

    @property
    def identity(self) -> bool:
        return self.scale == 1.0

    def apply(self, points: np.ndarray) -> np.ndarray:
        """points (..., 3) m -> (..., 3) float64 m, in the trained range's frame."""
        p = np.asarray(points, dtype=np.float64)
        return p if self.identity else self.pivot + self.scale * (p - self.pivot)


def body_scale(body_vertices: np.ndarray, pelvis: np.ndarray, heights: tuple[float, float]) -> BodyScale:
    """The scaling that brings a body into a trained range of heights.

    body_vertices (V, 3) m, Y-up, rest pose; pelvis (3,) m, the root joint; heights (lowest, tallest) m of
    the bodies trained on. Scale = clamp(height, lowest, tallest) / height (1 inside the range), about the
    point on the body's floor (its lowest Y) under the pelvis.
    """
    lo, hi = float(heights[0]), float(heights[1])
    if not 0 < lo <= hi:
        raise ValueError(f"heights must be 0 < lowest <= tallest, got {heights}")
    h = body_height(body_vertices)
    target = min(max(h, lo), hi)
    pelvis = np.asarray(pelvis, dtype=np.float64)
    pivot = np.array([pelvis[0], float(np.asarray(body_vertices)[:, 1].min()), pelvis[2]])
    return BodyScale(scale=1.0 if target == h else target / h, pivot=pivot)
