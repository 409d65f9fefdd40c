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
    """p -> pivot + scale * (p - pivot). scale (3,) float64, dimensionless, per axis; pivot (3,) float64 m."""

    scale: np.ndarray
    pivot: np.ndarray

    @property
    def identity(self) -> bool:
        return bool(np.all(self.scale == 1.0))

    def unscale(self, displacements: np.ndarray) -> np.ndarray:
        """displacements (..., 3) m read in the scaled frame -> (..., 3) float32 m on the body."""
        return (np.asarray(displacements) / self.scale).astype(np.float32)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """points (..., 3) m -> (..., 3) float64 m, in the trained range's frame."""
        p = np.asarray(points, dtype=np.float64)
        return p if self.identity else self.pivot + self.scale * (p - self.pivot)


def torso_size(vertices: np.ndarray, joints: np.ndarray) -> tuple[float, float]:
    """vertices (V, 3) m, joints (24, 3) m in SMPL's order, T-pose rest -> (width along X, depth along Z) m of
    the torso: the vertices between the pelvis and spine3 heights, within the shoulder joints."""
    v, j = np.asarray(vertices, dtype=np.float64), np.asarray(joints, dtype=np.float64)
    pelvis, spine3, left_shoulder, right_shoulder = j[0], j[9], j[16], j[17]
    half = abs(left_shoulder[0] - right_shoulder[0]) / 2
    torso = v[(v[:, 1] > pelvis[1]) & (v[:, 1] < spine3[1]) & (np.abs(v[:, 0] - pelvis[0]) < half)]
    return float(np.ptp(torso[:, 0])), float(np.ptp(torso[:, 2]))


def _clamped(value: float, bounds: tuple[float, float], name: str) -> float:
    lo, hi = float(bounds[0]), float(bounds[1])
    if not 0 < lo <= hi:
        raise ValueError(f"{name} must be 0 < lowest <= highest, got {bounds}")
    return 1.0 if lo <= value <= hi else min(max(value, lo), hi) / value


def body_scale(body_vertices: np.ndarray, joints: np.ndarray, heights: tuple[float, float],
               torso: tuple[tuple[float, float], tuple[float, float]] | None = None) -> BodyScale:
    """The scaling that brings a body into a trained range of heights (and, with `torso`, of torso sizes).

    body_vertices (V, 3) m, Y-up, T-pose rest; joints (24, 3) m, SMPL's order; heights (lowest, tallest) m of
    the bodies trained on. Uniform scale = clamp(height, lowest, tallest) / height (1 inside the range), about
    the point on the body's floor (its lowest Y) under the pelvis. torso ((width lo, hi), (depth lo, hi)) m
    (`torso_size` of the trained bodies): then X and Z are scaled further, each so that the uniformly scaled
    torso's width and depth fall in their ranges.
    """
    v = np.asarray(body_vertices, dtype=np.float64)
    j = np.asarray(joints, dtype=np.float64)
    uniform = _clamped(body_height(v), heights, "heights")
    scale = np.full(3, uniform)
    if torso is not None:
        width, depth = torso_size(v * uniform, j * uniform)
        scale[0] *= _clamped(width, torso[0], "torso widths")
        scale[2] *= _clamped(depth, torso[1], "torso depths")
    pivot = np.array([j[0, 0], float(v[:, 1].min()), j[0, 2]])
    return BodyScale(scale=scale, pivot=pivot)
