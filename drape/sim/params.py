"""Intrinsic simulation parameters: a typed, validated config and a seeded sampler.

The intrinsic parameters are what Wang et al. 2019 hold fixed inside one
"intrinsic garment space": the material (Young's modulus, Poisson ratio,
thickness, areal density, damping), the environment (gravity, air drag) and the
solver (contact softness and margin, substeps, iterations).

`SAMPLE_RANGES` are the ranges the sampler draws from. They were found by the
procedure of Wang 2019 Sec. 3.6 (vary one parameter from the base until the
simulation fails a quality gate or looks wrong) with `drape sim sweep`; the
measured table is in docs/sim.md (raw rows: docs/sim_sweep.json).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator


class SimParams(BaseModel):
    """One set of intrinsic parameters (SI units)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    young: float = Field(default=2.0e5, gt=0, le=1e9, description="Young's modulus of the shell, Pa")
    poisson: float = Field(default=0.3, ge=0.0, lt=0.5, description="Poisson ratio")
    thickness: float = Field(default=1.0e-3, gt=0, le=0.02, description="shell thickness, m (bending ~ young * thickness^3)")
    density: float = Field(default=0.2, gt=0, le=5.0, description="areal density, kg/m^2 (mass = density * area)")
    damping: float = Field(default=1.0e-4, ge=0, le=1.0, description="material (Rayleigh) damping of the elasticity, s")
    gravity: float = Field(default=9.81, ge=0, le=30.0, description="gravity along -Y, m/s^2")
    air_drag: float = Field(default=0.2, ge=0, le=20.0, description="air drag, N s/m per m^2 of cloth: f_i = -c * area_i * v_i")
    contact_margin: float = Field(default=0.001, ge=0, le=0.03, description="contact margin around the body, m")
    contact_timeconst: float = Field(default=0.01, gt=0, le=0.2, description="contact softness: solref time constant, s")
    friction: float = Field(default=0.6, ge=0, le=2.0, description="cloth-body friction coefficient")
    substeps: int = Field(default=4, ge=1, le=64, description="simulation steps per motion frame")
    iterations: int = Field(default=30, ge=1, le=500, description="constraint-solver iterations per step")

    def to_json(self) -> str:
        return self.model_dump_json()

    @classmethod
    def from_file(cls, path: str | Path) -> SimParams:
        return cls.model_validate_json(Path(path).read_text())


# name -> (low, high, log-uniform?) for the sampler; see docs/sim.md for how they were found
SAMPLE_RANGES: dict[str, tuple[float, float, bool]] = {
    "young": (3.0e4, 3.0e6, True),  # 1e4 Pa stretched 2.7% on average: rubber, not cloth
    "poisson": (0.0, 0.45, False),
    "thickness": (3.0e-4, 3.0e-3, True),
    "density": (0.05, 0.6, True),  # woven fabrics weigh 0.05-0.5 kg/m^2
    "damping": (0.0, 1.0e-3, False),
    "gravity": (5.0, 15.0, False),
    "air_drag": (0.0, 5.0, False),  # at 20 the hem of a walking skirt rose 4 cm: a gale
}

def sample_params(n: int, seed: int = 0, base: SimParams | None = None) -> list[SimParams]:
    """n parameter sets drawn within SAMPLE_RANGES (log-uniform where marked); the rest from base."""
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    rng = np.random.default_rng(seed)
    base = base or SimParams()
    out = []
    for _ in range(n):
        values = base.model_dump()
        for name, (lo, hi, log) in SAMPLE_RANGES.items():
            u = float(rng.random())
            values[name] = math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))) if log else lo + u * (hi - lo)
        out.append(SimParams(**values))
    return out


CLOTH_RADIUS = 0.001  # m, a cloth flex's collision radius (the inner layer's is set from its thickness)
MIN_INNER_RADIUS = 0.0005  # m, the least collision radius the inner layer of two gets
# the outer cloth's own contact thickness at the default margin (radius + margin) plus the inner's least
# (its least radius + margin): the smallest H_in the defaults allow (drape.sim.layers says how H_in is realised)
MIN_INNER_THICKNESS = round(CLOTH_RADIUS + MIN_INNER_RADIUS + 2 * 0.001, 9)


class LayerParams(SimParams):
    """A parameter set for two layers: the shared intrinsic parameters plus the inner garment's thickness.

    inner_thickness (H_in): the distance the outer cloth's mid-surface keeps from the inner's where they
    touch (m); MGN (Shi et al. 2025) conditions the outer garment on it. How the simulation realises it:
    drape.sim.layers.
    """

    inner_thickness: float = Field(default=0.006, ge=MIN_INNER_THICKNESS, le=0.03,
                                   description="inner garment thickness H_in: outer-to-inner mid-surface gap, m")

    @model_validator(mode="after")
    def _room_for_the_inner_layer(self) -> LayerParams:
        least = CLOTH_RADIUS + MIN_INNER_RADIUS + 2 * self.contact_margin
        if self.inner_thickness < least:
            raise ValueError(f"inner_thickness {self.inner_thickness} m is below {least:.4g} m: the outer cloth's "
                             "radius + margin, plus the inner's least radius + margin (contact_margin each)")
        return self

    @property
    def inner_radius(self) -> float:
        """The inner flex's collision radius that makes the outer-to-inner rest gap inner_thickness, m."""
        return self.inner_thickness - CLOTH_RADIUS - 2 * self.contact_margin

    @classmethod
    def from_file(cls, path: str | Path) -> LayerParams:
        return cls.model_validate_json(Path(path).read_text())


def thickness_values(n: int, low: float, high: float, held_out: int, seed: int = 0) -> list[float]:
    """n inner thicknesses in [low, high], one per equal bin; the last `held_out` (the held-out parameter
    sets of `dataset.splits`) get bins spread over the interior, so no training value shares their bin.

    Training values fill the other bins in a seeded order; each value is uniform within its bin.
    """
    if n < 1 or not 0 <= held_out < n:
        raise ValueError(f"need n >= 1 and 0 <= held_out < n, got n={n}, held_out={held_out}")
    if not MIN_INNER_THICKNESS <= low <= high:
        raise ValueError(f"thickness range must satisfy {MIN_INNER_THICKNESS} <= low <= high, got {low}, {high}")
    rng = np.random.default_rng([seed, 22])
    test_bins = [int(round(x)) for x in np.linspace(0, n - 1, held_out + 2)[1:-1]] if held_out else []
    train_bins = [b for b in range(n) if b not in test_bins]
    order = list(rng.permutation(train_bins)) + test_bins
    width = (high - low) / n
    return [low + (b + float(rng.random())) * width for b in order]


def sample_layer_params(n: int, seed: int = 0, thickness: tuple[float, float] = (0.004, 0.012),
                        held_out: int = 2, base: SimParams | None = None,
                        material: str = "sampled") -> list[LayerParams]:
    """n two-layer parameter sets: `thickness_values` for H_in, with the other parameters
    `sample_params(n, seed)` (material="sampled") or all `base` (material="fixed": one cloth, as MGN, whose
    outer network is conditioned on H_in alone)."""
    if material not in ("sampled", "fixed"):
        raise ValueError(f"material must be 'sampled' or 'fixed', got {material!r}")
    h = thickness_values(n, thickness[0], thickness[1], held_out, seed)
    rest = sample_params(n, seed, base) if material == "sampled" else [base or SimParams()] * n
    return [LayerParams(**p.model_dump(), inner_thickness=t) for p, t in zip(rest, h, strict=True)]
