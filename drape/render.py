"""Still images of bodies and garments (matplotlib, no display needed).

A frame is drawn as shaded triangles, back to front (painter's algorithm), in an
orthographic view turned `azimuth` degrees about +Y from the front (+Z) view.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drape.geometry.mesh import face_normals


@dataclass
class Layer:
    """One mesh in every frame: vertices (T, N, 3) metres, faces (F, 3), an RGB colour in [0, 1]."""

    vertices: np.ndarray
    faces: np.ndarray
    color: tuple[float, float, float]


def view_matrix(azimuth_deg: float) -> np.ndarray:
    a = np.radians(azimuth_deg)
    # rows: screen x, screen y, depth toward the viewer
    return np.array([[np.cos(a), 0.0, -np.sin(a)], [0.0, 1.0, 0.0], [np.sin(a), 0.0, np.cos(a)]])


def render_frames(
    layers: Sequence[Layer],
    frames: Sequence[int],
    out: str | Path,
    azimuth: float = 25.0,
    titles: Sequence[str] | None = None,
    panel_size: float = 3.0,
    caption: str | None = None,
    follow_all: bool = False,
) -> Path:
    """Draw the chosen frames side by side into a PNG at `out`; each panel follows the first layer (or the
    mean of all layers with follow_all)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    view = view_matrix(azimuth)
    light = np.array([0.3, 0.5, 1.0])
    light /= np.linalg.norm(light)
    fig, axes = plt.subplots(1, len(frames), figsize=(panel_size * len(frames), panel_size * 1.6))
    axes = np.atleast_1d(axes)
    for ax, t, k in zip(axes, frames, range(len(frames)), strict=True):
        polys, depth, colors = [], [], []
        centre = (np.mean([layer.vertices[t].mean(axis=0) for layer in layers], axis=0) if follow_all
                  else layers[0].vertices[t].mean(axis=0))
        for rank, layer in enumerate(layers):
            v = (layer.vertices[t] - centre) @ view.T  # (N, 3) screen coords
            tri = v[layer.faces]
            n = face_normals(v, layer.faces)
            shade = 0.35 + 0.65 * np.abs(n @ light)  # two-sided: cloth has no inside
            polys.append(tri[:, :, :2])
            # later layers (cloth over the body) win ties: a centroid sort alone interleaves
            # triangles that lie a centimetre apart
            depth.append(tri[:, :, 2].mean(axis=1) + 0.02 * rank)
            colors.append(np.clip(shade[:, None] * np.asarray(layer.color)[None], 0, 1))
        p, d, c = np.concatenate(polys), np.concatenate(depth), np.concatenate(colors)
        order = np.argsort(d)
        ax.add_collection(PolyCollection(list(p[order]), facecolors=c[order], edgecolors="none"))
        ax.set_xlim(-1.0, 1.0)
        ax.set_ylim(-1.1, 1.1)
        ax.set_aspect("equal")
        ax.axis("off")
        ax.set_title(titles[k] if titles else f"frame {t}", fontsize=9)
    if caption:
        fig.suptitle(caption, fontsize=9, y=0.04)
    fig.tight_layout()
    out = Path(out)
    if not out.suffix:  # matplotlib appends .png itself: return the file it writes, not `out`
        out = out.with_name(out.name + ".png")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
