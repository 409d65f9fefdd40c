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
from pydantic import BaseModel, ConfigDict, Field


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
