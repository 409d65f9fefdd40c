"""Two garments layered on one body: an inner and an outer cloth simulated together (issue 22, for MGN).

Both garments are flexes in one MuJoCo 4 model (`simulate.simulate_cloths`, the single-garment engine) with
the same kinematic body hulls, intrinsic parameters, pinned top boundaries and air drag as one garment. Who
collides with whom is set by MuJoCo's bitmasks (a pair collides when one side's contype shares a bit with
the other's conaffinity):

    body hulls  contype 1, conaffinity 0
    inner       contype 2, conaffinity 1   -> the body
    outer       contype 0, conaffinity 3   -> the body and the inner

so the inner collides with the body, the outer with the body and the inner, and neither with itself.

The inner garment's thickness H_in (`LayerParams.inner_thickness`) is the distance the outer cloth's
mid-surface keeps from the inner's. MuJoCo 4 measures a flex contact between the radius-thickened surfaces
and adds both sides' margins (measured on two cloths over a sphere: radius and margin of the inner moved the
outer by the same amount), so mid-surfaces rest r_in + m_in + r_out + m_out apart. The outer keeps the
single-garment settings (r_out = 1 mm, m_out = contact_margin); the inner's radius takes the rest:
r_in = H_in - r_out - 2 contact_margin (m_in = contact_margin). The same radius holds the inner off the
body: its mid-surface rests H_in - r_out - contact_margin from the skin (half of a physical thickness
2 (H_in - 2 mm), as a thick garment's mid-surface would; the outer's rest 2 mm off it where it meets the
skin directly, as a single garment's).

Rest shapes: generate the two garments as one layered outfit and split it (`split_outfit`), so the outer is
built around the inner and the two start apart.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drape.assets.body import Body
from drape.assets.motion import Motion
from drape.assets.outfits import split_outfit
from drape.sim.collider import Hull
from drape.sim.params import CLOTH_RADIUS, LayerParams
from drape.sim.quality import layer_stats
from drape.sim.simulate import Cloth, simulate_cloths

__all__ = ["LayerResult", "layer_cloths", "simulate_layers", "split_outfit"]


@dataclass
class LayerResult:
    """inner_vertices (T, Ni, 3), outer_vertices (T, No, 3) float32 m; poses (T, 24, 3) float32 rad;
    trans (T, 3) float32 m; stats: `quality.layer_stats`; seconds: wall time of the simulation."""

    inner_vertices: np.ndarray
    outer_vertices: np.ndarray
    poses: np.ndarray
    trans: np.ndarray
    params: LayerParams
    stats: dict
    seconds: float
    settle_frames: int

    @property
    def seconds_per_frame(self) -> float:
        return self.seconds / (len(self.inner_vertices) + self.settle_frames)


def layer_cloths(inner_vertices: np.ndarray, inner_faces: np.ndarray, outer_vertices: np.ndarray,
                 outer_faces: np.ndarray, params: LayerParams) -> list[Cloth]:
    """The two flexes with the collision settings above."""
    m = params.contact_margin
    return [
        Cloth("inner", np.asarray(inner_vertices, np.float64), np.asarray(inner_faces, np.int64),
              radius=params.inner_radius, margin=m, contype=2, conaffinity=1),
        Cloth("outer", np.asarray(outer_vertices, np.float64), np.asarray(outer_faces, np.int64),
              radius=CLOTH_RADIUS, margin=m, contype=0, conaffinity=3),
    ]


def simulate_layers(
    inner_vertices: np.ndarray,
    inner_faces: np.ndarray,
    outer_vertices: np.ndarray,
    outer_faces: np.ndarray,
    body: Body,
    motion: Motion,
    params: LayerParams | None = None,
    frames: int | None = None,
    settle_blend: int = 15,
    settle_hold: int = 15,
    pin_top: bool = True,
    hulls: list[Hull] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LayerResult:
    """Simulate an inner and an outer garment (both in rest pose on `body`, the outer around the inner)
    together along `motion`; arguments as `simulate.simulate`."""
    params = params or LayerParams()
    cloths = layer_cloths(inner_vertices, inner_faces, outer_vertices, outer_faces, params)
    run = simulate_cloths(cloths, body, motion, params, frames, settle_blend, settle_hold, pin_top, hulls, progress)
    inner, outer = run.vertices
    T, S = len(run.poses), run.settle_frames
    stats = layer_stats(inner, cloths[0].vertices.astype(np.float32), cloths[0].faces,
                        outer, cloths[1].vertices.astype(np.float32), cloths[1].faces, body, run.poses, run.trans)
    stats["inner_thickness_m"] = params.inner_thickness
    stats["seconds"] = round(run.seconds, 3)
    stats["seconds_per_frame"] = round(run.seconds / (T + S), 4)
    return LayerResult(inner, outer, run.poses, run.trans, params, stats, run.seconds, S)
