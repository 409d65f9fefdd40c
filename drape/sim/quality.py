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
from drape.geometry.queries import MeshDistance


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
