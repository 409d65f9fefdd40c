"""MGN's inner-layer network (Shi et al. 2025, after PBNS): a pose MLP -> per-vertex offsets through a learned
basis P_D2G, then skinning with weights taken from the body. One network per inner garment template.

Shapes: B frames, N template vertices, K basis size. Metres, radians.
  poses (B, 72) axis-angle (the root's 3 values ignored: the deformation is pose-space, in the body's frame)
  -> coefficients (B, K) (unbounded, linear)
  -> offsets (B, N, 3) = coefficients @ P_D2G, P_D2G (K, N, 3)
  -> posed vertices = LBS(template + offsets, W, FK(poses)), W (N, 24) fixed, from the body.

This is the same posing as a DeePSD rig (weights + blend shapes + pose keys), so the runtime serves it with the
same batched posing (drape.runtime.deepsd.pose_outfit): the coefficients are the keys, P_D2G the blend shapes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from drape.models.deepsd import NUM_JOINTS, mlp


@dataclass(frozen=True)
class InnerConfig:
    num_vertices: int
    num_basis: int = 64  # K
    width: int = 256  # the pose MLP's hidden width
    depth: int = 3  # hidden layers of the pose MLP
    basis_init: float = 1e-4  # metres: P_D2G starts this small (the template, skinned)

    def to_dict(self) -> dict:
        return asdict(self)


class InnerPSD(nn.Module):
    """poses (B, 72) -> offsets (B, N, 3) m in rest space; `coefficients` gives the (B, K) keys alone."""

    def __init__(self, cfg: InnerConfig):
        super().__init__()
        self.cfg = cfg
        self.pose = mlp([(NUM_JOINTS - 1) * 3] + [cfg.width] * cfg.depth + [cfg.num_basis])
        self.basis = nn.Parameter(torch.randn(cfg.num_basis, cfg.num_vertices, 3) * cfg.basis_init)

    def coefficients(self, poses: torch.Tensor) -> torch.Tensor:
        return self.pose(poses[:, 3:])

    def forward(self, poses: torch.Tensor) -> torch.Tensor:
        return torch.einsum("bk,knc->bnc", self.coefficients(poses), self.basis)


class InnerCoefficientsGraph(nn.Module):
    """The exported form: poses (T, 72) -> pose_keys (T, K) (the basis ships beside it as blend shapes)."""

    def __init__(self, model: InnerPSD):
        super().__init__()
        self.model = model

    def forward(self, poses: torch.Tensor) -> torch.Tensor:
        return self.model.coefficients(poses)
