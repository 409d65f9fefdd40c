"""Meshes with known answers for the geometry tests."""

import numpy as np
import trimesh


def sphere(radius: float = 1.0, subdiv: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere: vertices (N, 3) at `radius`, outward-facing faces (F, 3)."""
    m = trimesh.creation.icosphere(subdivisions=subdiv, radius=radius)
    return np.asarray(m.vertices), np.asarray(m.faces)
