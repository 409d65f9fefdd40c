"""Mesh files (OBJ, PLY, GLB/glTF) through trimesh, as plain arrays.

vertices: (N, 3) float32 metres; faces: (F, 3) int32. Vertex order is kept as
stored (no merging or reordering), so per-vertex results map back to the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")


def load_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh; several meshes in one file (glTF scenes) are concatenated."""
    import trimesh

    mesh = cast(trimesh.Trimesh, trimesh.load(str(path), process=False, force="mesh", maintain_order=True))
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int32)


def save_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """Write a triangle mesh; the format follows the file's suffix."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"unsupported mesh suffix {path.suffix!r}; use one of {MESH_SUFFIXES}")
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), process=False).export(str(path))
    return path
