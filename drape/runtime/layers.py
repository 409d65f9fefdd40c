"""The served layer combinations (issue 22): an inner and an outer garment template worn together.

Each combination is one generated layered outfit (drape.assets.outfits.split_outfit: the outer built around the
inner, VERTICES together, a fixed seed) split into its two templates, on the neutral body. Until the MGN
networks are trained, both layers are posed by DeePSD's served rig, each rigged on its own, and the post step
between layers (drape.geometry.layers) keeps the outer out of the inner: the `model` of every combination says
so ("deepsd"). The templates are made on first use (about 1.5 s each combination) and kept.

Shapes: template vertices (N, 3) float32 metres in rest pose on the body; faces (F, 3) int32.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from drape.assets.outfits import split_outfit

COMBINATIONS = (("tshirt", "jacket"), ("tanktop", "longsleeve"))  # (inner, outer) garment types
VERTICES = 4000  # both layers together
SEED = 7
BODY = "neutral"
THICKNESS = (0.002, 0.02)  # metres: the inner thicknesses the post step between layers is served for
MODEL = "deepsd"  # what poses the layers: DeePSD's rig of each layer, then the post step between them


@dataclass(frozen=True)
class LayerTemplate:
    """One layer's template: name, role ('inner' | 'outer'), body, vertices (N, 3) float32 m, faces (F, 3) int32."""

    name: str
    role: str
    body: str
    vertices: np.ndarray
    faces: np.ndarray

    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    def info(self) -> dict:
        """The template's entry in GET /v1/garments."""
        return {"name": self.name, "num_vertices": self.num_vertices, "num_faces": int(len(self.faces)),
                "body": self.body, "models": [MODEL]}


@dataclass(frozen=True)
class LayerCombination:
    """An inner and an outer template worn together, and the inner thicknesses served, (min, max) m."""

    inner: LayerTemplate
    outer: LayerTemplate
    thickness: tuple[float, float] = THICKNESS
    model: str = MODEL


class LayerCatalog:
    """The served combinations (COMBINATIONS), made on first use; thread-safe."""

    def __init__(self, combinations: tuple[tuple[str, str], ...] = COMBINATIONS):
        self._kinds = combinations
        self._made: list[LayerCombination] | None = None
        self._lock = threading.Lock()

    def combinations(self) -> list[LayerCombination]:
        with self._lock:
            if self._made is None:
                made = []
                for inner, outer in self._kinds:
                    (vi, fi), (vo, fo) = split_outfit(f"{inner},{outer}", VERTICES, seed=SEED, body=BODY)
                    made.append(LayerCombination(LayerTemplate(inner, "inner", BODY, vi, fi),
                                                 LayerTemplate(outer, "outer", BODY, vo, fo)))
                self._made = made
            return self._made

    def templates(self) -> list[LayerTemplate]:
        """Every served layer template, once each, in the combinations' order."""
        seen: dict[str, LayerTemplate] = {}
        for c in self.combinations():
            for t in (c.inner, c.outer):
                seen.setdefault(t.name, t)
        return list(seen.values())

    def template(self, name: str) -> LayerTemplate | None:
        return next((t for t in self.templates() if t.name == name), None)

    def find(self, inner: str, outer: str) -> LayerCombination | None:
        return next((c for c in self.combinations() if c.inner.name == inner and c.outer.name == outer), None)
