"""MGN's two layer networks (Shi et al. 2025). One network per garment template.

Inner layer (`InnerPSD`, after PBNS): a pose MLP -> per-vertex offsets through a learned basis P_D2G, then
skinning with weights taken from the body.

Shapes: B frames, N template vertices, K basis size. Metres, radians.
  poses (B, 72) axis-angle (the root's 3 values ignored: the deformation is pose-space, in the body's frame)
  -> coefficients (B, K) (unbounded, linear)
  -> offsets (B, N, 3) = coefficients @ P_D2G, P_D2G (K, N, 3)
  -> posed vertices = LBS(template + offsets, W, FK(poses)), W (N, 24) fixed, from the body.

This is the same posing as a DeePSD rig (weights + blend shapes + pose keys), so the runtime serves it with the
same batched posing (drape.runtime.deepsd.pose_outfit): the coefficients are the keys, P_D2G the blend shapes.

Outer layer (`OuterTransformer`): a Transformer encoder-decoder over a window of W frames. The encoder reads the
motion (drape.geometry.character_space.motion_features, (B, W, 78)) with the inner thickness H_in appended to
every frame; the decoder reads the inner layer's deformation (its network's pose keys, (B, W, Ki), the inner
basis' coefficients) with H_in appended; both standardised by the training frames' mean and std, embedded to
d_model with sinusoidal positions. Out: (B, W, K)
coefficients of the outer template's own learned basis (K, No, 3), posed as the inner layer is.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from drape.geometry.character_space import MOTION_FEATURES
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


@dataclass(frozen=True)
class OuterConfig:
    num_vertices: int  # No, the outer template's
    num_inner_keys: int = 64  # Ki, the inner network's basis size
    num_basis: int = 128  # K
    d_model: int = 256
    heads: int = 4
    layers: int = 2  # encoder layers; as many decoder layers
    feedforward: int = 512
    window: int = 30  # W, frames per window (trained and served)
    dropout: float = 0.1
    basis_init: float = 1e-4  # metres

    def to_dict(self) -> dict:
        return asdict(self)


def sinusoid(length: int, width: int) -> torch.Tensor:
    """(length, width) sinusoidal positions (Vaswani et al.)."""
    pos = torch.arange(length, dtype=torch.float32)[:, None]
    freq = torch.exp(torch.arange(0, width, 2, dtype=torch.float32) * (-math.log(10000.0) / width))
    out = torch.zeros(length, width)
    out[:, 0::2] = torch.sin(pos * freq)
    out[:, 1::2] = torch.cos(pos * freq)
    return out


THICKNESS_SCALE = 100.0  # H_in enters the network in centimetres


class OuterTransformer(nn.Module):
    """(motion (B, W, 78), thickness (B, 1) m, inner_keys (B, W, Ki)) -> coefficients (B, W, K); `forward`
    gives offsets (B, W, No, 3) m in rest space."""

    positions: torch.Tensor
    motion_mean: torch.Tensor
    motion_std: torch.Tensor
    keys_mean: torch.Tensor
    keys_std: torch.Tensor

    def __init__(self, cfg: OuterConfig):
        super().__init__()
        self.cfg = cfg
        self.motion_in = nn.Linear(MOTION_FEATURES + 1, cfg.d_model)
        self.inner_in = nn.Linear(cfg.num_inner_keys + 1, cfg.d_model)
        self.transformer = nn.Transformer(cfg.d_model, cfg.heads, cfg.layers, cfg.layers, cfg.feedforward,
                                          cfg.dropout, batch_first=True)
        self.out = nn.Linear(cfg.d_model, cfg.num_basis)
        self.register_buffer("positions", sinusoid(max(cfg.window, 512), cfg.d_model), persistent=False)
        # input standardisation, set from the training data (`set_normalization`), saved and exported with it
        self.register_buffer("motion_mean", torch.zeros(MOTION_FEATURES))
        self.register_buffer("motion_std", torch.ones(MOTION_FEATURES))
        self.register_buffer("keys_mean", torch.zeros(cfg.num_inner_keys))
        self.register_buffer("keys_std", torch.ones(cfg.num_inner_keys))
        self.basis = nn.Parameter(torch.randn(cfg.num_basis, cfg.num_vertices, 3) * cfg.basis_init)

    def set_normalization(self, motion: torch.Tensor, inner_keys: torch.Tensor, floor: float = 1e-3) -> None:
        """motion (M, 78), inner_keys (M, Ki): the training frames' inputs; std floored at `floor`."""
        self.motion_mean.copy_(motion.mean(0))
        self.motion_std.copy_(motion.std(0).clamp_min(floor))
        self.keys_mean.copy_(inner_keys.mean(0))
        self.keys_std.copy_(inner_keys.std(0).clamp_min(floor))

    def coefficients(self, motion: torch.Tensor, thickness: torch.Tensor, inner_keys: torch.Tensor) -> torch.Tensor:
        w = motion.shape[1]
        h = (thickness * THICKNESS_SCALE)[:, None, :].expand(-1, w, 1)
        pos = self.positions[:w][None]
        motion = (motion - self.motion_mean) / self.motion_std
        inner_keys = (inner_keys - self.keys_mean) / self.keys_std
        src = self.motion_in(torch.cat([motion, h], dim=-1)) + pos
        tgt = self.inner_in(torch.cat([inner_keys, h], dim=-1)) + pos
        return self.out(self.transformer(src, tgt))

    def forward(self, motion: torch.Tensor, thickness: torch.Tensor, inner_keys: torch.Tensor) -> torch.Tensor:
        return torch.einsum("bwk,knc->bwnc", self.coefficients(motion, thickness, inner_keys), self.basis)


class OuterCoefficientsGraph(nn.Module):
    """The exported form: (motion (B, W, 78), thickness (B, 1), inner_keys (B, W, Ki)) -> outer_keys (B, W, K)."""

    def __init__(self, model: OuterTransformer):
        super().__init__()
        self.model = model

    def forward(self, motion: torch.Tensor, thickness: torch.Tensor, inner_keys: torch.Tensor) -> torch.Tensor:
        return self.model.coefficients(motion, thickness, inner_keys)
