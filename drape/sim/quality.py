"""Quality statistics and the gate every simulated sequence must pass.

Penetration is measured against the real (high-resolution) body mesh, posed by
linear blend skinning: for every garment vertex of every frame, the exact
closest-triangle signed distance (negative inside); penetration = max(0, -d).
Edge strain is |l / l_rest - 1| over the garment's unique edges.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from drape.assets.body import Body
from drape.geometry.mesh import unique_edges, vertex_normals
from drape.geometry.queries import MeshDistance, OpenSurfaceDistance


class QualityGate(BaseModel):
    """Limits a sequence must meet to enter a dataset (metres; strain is a ratio)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_penetration_p99: float = Field(default=0.005, ge=0, description="99th percentile penetration into the body, m")
    max_penetration: float = Field(default=0.03, ge=0, description="largest penetration into the body, m")
    max_mean_strain: float = Field(default=0.05, ge=0, description="mean |l / l_rest - 1| over edges and frames")
    max_strain_p99: float = Field(default=0.25, ge=0, description="99th percentile edge strain")

    def failures(self, stats: dict) -> list[str]:
        """Reasons the sequence fails (empty when it passes)."""
        if not stats["finite"]:
            return ["non-finite vertex positions"]
        out = []
        checks = [
            ("penetration_p99_m", self.max_penetration_p99),
            ("penetration_max_m", self.max_penetration),
            ("strain_mean", self.max_mean_strain),
            ("strain_p99", self.max_strain_p99),
        ]
        for key, limit in checks:
            if stats[key] > limit:
                out.append(f"{key} = {stats[key]:.4g} > {limit:.4g}")
        return out


def penetration(vertices: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray) -> np.ndarray:
    """vertices (T, N, 3), posed body (T, M, 3) -> (T, N) penetration depth, m (0 outside)."""
    out = np.zeros(vertices.shape[:2])
    for t in range(len(vertices)):
        bv = body_vertices[t]
        md = MeshDistance(bv, body_faces, vertex_normals(bv, body_faces))
        out[t] = np.maximum(-md.signed_distance(vertices[t]), 0.0)
    return out


def edge_strain(vertices: np.ndarray, rest: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """vertices (T, N, 3), rest (N, 3) -> (T, E) |l / l_rest - 1|."""
    e = unique_edges(faces)
    l0 = np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)
    ln = np.linalg.norm(vertices[:, e[:, 0]] - vertices[:, e[:, 1]], axis=2)
    return np.abs(ln / np.maximum(l0, 1e-12) - 1.0)


def sequence_stats(
    vertices: np.ndarray, rest: np.ndarray, faces: np.ndarray, body: Body, poses: np.ndarray, trans: np.ndarray
) -> dict:
    """Quality statistics of one simulated sequence (JSON-ready floats)."""
    finite = bool(np.isfinite(vertices).all())
    stats: dict = {"finite": finite, "frames": int(len(vertices)), "vertices": int(vertices.shape[1])}
    if not finite:
        return stats | {k: float("inf") for k in (
            "penetration_p99_m", "penetration_max_m", "inside_share", "strain_mean", "strain_p99", "strain_max")}
    pen = penetration(vertices, body.pose(poses, trans), body.faces)
    strain = edge_strain(vertices, rest, faces)
    stats |= {
        "penetration_p99_m": float(np.percentile(pen, 99)),
        "penetration_max_m": float(pen.max()),
        "inside_share": float((pen > 0).mean()),
        "strain_mean": float(strain.mean()),
        "strain_p99": float(np.percentile(strain, 99)),
        "strain_max": float(strain.max()),
        "mean_height_m": float((vertices[..., 1] - trans[:, None, 1]).mean()),
    }
    return stats


# -- two layers ---------------------------------------------------------------------------------------------

# outer vertices are judged inside the inner layer only within this distance of it: farther away, where an open,
# folding, self-intersecting inner sheet has no well-defined inside, the side flips between frames at constant
# distance (measured: jacket vertices under the arm 3-6 cm from a t-shirt's armpit fold); an outer layer that
# went through the inner sits between it and the body, within the inner's clearance of the body
INSIDE_BAND = 0.02

LAYER_KEYS = ("penetration_p99_m", "penetration_max_m", "inside_share", "strain_mean", "strain_p99", "strain_max",
              "mean_height_m")


def outer_inner_distance(outer: np.ndarray, inner: np.ndarray, inner_faces: np.ndarray,
                         reach: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance of each outer vertex to the inner layer, frame by frame.

    outer (T, No, 3), inner (T, Ni, 3) -> (sd (T, No) m, covered (T, No) bool). sd: exact distance to the
    closest point of the inner mesh, negative when the outer vertex is behind the inner layer (inside it),
    the side taken from the pseudo-normal at the closest point (the face's normal inside a face, the two
    faces' on an edge, the angle-weighted vertex normal at a vertex: exact, where an interpolated vertex normal
    flips sign at creases for points centimetres away). covered: the closest point is not on the inner's
    boundary (hems, cuffs, necklines, an open front): an outer vertex past the inner's edge (a jacket's sleeve
    below a t-shirt's) sees that edge as its closest point, where no side is defined, so only covered vertices
    are judged. Points farther than `reach` are not judged either (MeshDistance is exact within it).
    """
    surface = OpenSurfaceDistance(inner_faces, inner.shape[1], reach=reach)
    sd = np.empty(outer.shape[:2])
    covered = np.empty(outer.shape[:2], dtype=bool)
    for t in range(len(outer)):
        s, _, _, c = surface.frame(inner[t]).query(outer[t])
        sd[t], covered[t] = s, c
    return sd, covered


def layer_stats(
    inner: np.ndarray, inner_rest: np.ndarray, inner_faces: np.ndarray,
    outer: np.ndarray, outer_rest: np.ndarray, outer_faces: np.ndarray,
    body: Body, poses: np.ndarray, trans: np.ndarray,
) -> dict:
    """Quality statistics of a two-layer sequence (JSON-ready floats).

    Each layer's single-garment statistics (`sequence_stats`) with an `inner_` / `outer_` prefix, plus
    outer-through-inner, as body penetration is measured: depth = how far an outer vertex is behind the
    inner layer (`outer_inner_distance`, judged within INSIDE_BAND of it), 0 elsewhere;
    `outer_in_inner_share` (vertex-frames with depth > 0, over all outer vertex-frames: MGN's L-Coll),
    `outer_in_inner_p99_m` (99th percentile depth over all outer vertex-frames), `outer_in_inner_max_m`;
    `outer_covered_share` (outer vertex-frames over the inner at all) and the outer-to-inner distance over
    covered vertex-frames (`outer_inner_gap_p10_m`, `_median_m`).
    """
    finite = bool(np.isfinite(inner).all() and np.isfinite(outer).all())
    stats: dict = {"finite": finite, "frames": int(len(inner)), "inner_vertices": int(inner.shape[1]),
                   "outer_vertices": int(outer.shape[1])}
    layer_keys = ("outer_in_inner_share", "outer_in_inner_p99_m", "outer_in_inner_max_m", "outer_covered_share",
                  "outer_inner_gap_p10_m", "outer_inner_gap_median_m")
    if not finite:
        return stats | {f"{p}_{k}": float("inf") for p in ("inner", "outer") for k in LAYER_KEYS} | {
            k: float("inf") for k in layer_keys}
    for prefix, v, rest, f in (("inner", inner, inner_rest, inner_faces), ("outer", outer, outer_rest, outer_faces)):
        one = sequence_stats(v, rest, f, body, poses, trans)
        stats |= {f"{prefix}_{k}": one[k] for k in LAYER_KEYS}
    sd, covered = outer_inner_distance(outer, inner, inner_faces)
    depth = np.where(covered & (sd < 0) & (sd >= -INSIDE_BAND), -sd, 0.0)
    gap = sd[covered]
    stats |= {
        "outer_in_inner_share": float((depth > 0).mean()),
        "outer_in_inner_p99_m": float(np.percentile(depth, 99)),
        "outer_in_inner_max_m": float(depth.max()),
        "outer_covered_share": float(covered.mean()),
        "outer_inner_gap_p10_m": float(np.percentile(gap, 10)) if len(gap) else float("nan"),
        "outer_inner_gap_median_m": float(np.median(gap)) if len(gap) else float("nan"),
    }
    return stats


class LayerGate(QualityGate):
    """The single-garment limits on each layer, plus outer-through-inner limits (see docs/sim.md)."""

    max_outer_in_inner_share: float = Field(default=0.02, ge=0, description="share of outer vertex-frames inside the inner layer")
    max_outer_in_inner_p99: float = Field(default=0.005, ge=0, description="99th percentile depth inside the inner layer, m")

    def failures(self, stats: dict) -> list[str]:
        if not stats["finite"]:
            return ["non-finite vertex positions"]
        out = []
        for prefix in ("inner", "outer"):
            one = {"finite": True} | {k: stats[f"{prefix}_{k}"] for k in LAYER_KEYS}
            out += [f"{prefix}_{why}" for why in super().failures(one)]
        for key, limit in (("outer_in_inner_share", self.max_outer_in_inner_share),
                           ("outer_in_inner_p99_m", self.max_outer_in_inner_p99)):
            if stats[key] > limit:
                out.append(f"{key} = {stats[key]:.4g} > {limit:.4g}")
        return out
