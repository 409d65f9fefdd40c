"""The layer routes' work (GET /v1/layers, POST /v1/layers/animate), knowing nothing of HTTP: the served
combinations, and a request checked into a plan (domain errors name the field)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drape.runtime.engine import Engine, RefineSettings
from drape.runtime.layers import LayerCombination, OuterModel
from drape.schemas.layers import LayerInfo, LayerList
from drape.service.errors import InvalidInput, LimitExceeded, NotFound, quoted
from drape.service.handlers import check_answer_size, check_motion, check_refine
from drape.service.settings import Settings


def layer_list(engine: Engine) -> LayerList:
    return LayerList(layers=[LayerInfo(inner=c.inner.name, outer=c.outer.name, body=c.inner.body,
                                       thickness=list(c.thickness), model=c.model,
                                       inner_model=c.inner.model, outer_model=c.outer.model)
                             for c in engine.layers.combinations()])


@dataclass(frozen=True)
class LayersPlan:
    """A checked layers animate request: the combination, the inner's thickness (m), the motion (poses
    (T, 24, 3) rad, translation (T, 3) m, fps) and the refinement settings (None: none)."""

    combination: LayerCombination
    thickness: float
    poses: np.ndarray
    translation: np.ndarray
    fps: float
    refine: RefineSettings | None

    @property
    def num_frames(self) -> int:
        return len(self.poses)


def find_combination(engine: Engine, inner: str, outer: str) -> LayerCombination:
    """The served combination of these templates: 404 naming an unknown template, 422 listing the combinations
    when the two are not worn together."""
    names = {t.name for t in engine.layers.templates()}
    for field, name in (("inner", inner), ("outer", outer)):
        if name not in names:
            raise NotFound(f"unknown layer template {quoted(name, 80)}; the served ones: "
                           f"{', '.join(sorted(names))} (GET /v1/layers)", field)
    combo = engine.layers.find(inner, outer)
    if combo is None:
        pairs = ", ".join(f"{c.inner.name} under {c.outer.name}" for c in engine.layers.combinations())
        raise InvalidInput(f"{inner!r} under {outer!r} is not served; the combinations: {pairs} (GET /v1/layers)",
                           "outer")
    return combo


def plan_layers(settings: Settings, engine: Engine, request: dict, max_posed: int | None) -> LayersPlan:
    """Check a layers animate request (a dict shaped like LayersAnimateRequest): both templates served (404
    naming the unknown one), worn together (422 listing the combinations), the thickness in the combination's
    range, the motion, and both layers' frames within the answer's bound."""
    combo = find_combination(engine, request["inner"], request["outer"])
    lo, hi = combo.thickness
    thickness = request["thickness"]
    if not lo <= thickness <= hi:
        raise InvalidInput(f"{thickness!r} m is outside the served range [{lo:g}, {hi:g}] m", "thickness")
    poses, translation, fps = check_motion(request["motion"], settings)
    network = combo.outer.network
    if isinstance(network, OuterModel):  # it reads the motion at its own rate: a slow motion is many more frames
        seconds = (len(poses) - 1) / fps  # float: an fps of 1e-300 makes it inf, not an overflow
        if seconds * network.fps + 1 > settings.max_frames:
            raise LimitExceeded(f"{len(poses)} frames at {fps:g} fps span {seconds:.6g} s, which the outer network "
                                f"reads at {network.fps:g} fps: over the limit of {settings.max_frames} frames "
                                f"({(settings.max_frames - 1) / network.fps:g} s)", "motion.fps")
    check_answer_size(len(poses), combo.inner.num_vertices + combo.outer.num_vertices, max_posed, "motion")
    return LayersPlan(combo, float(thickness), poses, translation, fps, check_refine(request["refine"]))
