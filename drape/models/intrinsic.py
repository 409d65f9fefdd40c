"""Intrinsic garment space (Wang, Shao, Fu, Mitra, SIGGRAPH Asia 2019), per garment template.

Everything is in the *character space* of the current frame: the world translated by minus the root
(pelvis) position and rotated by the inverse of the root's rotation (`character_space`).

- Shape autoencoder N_E / N_D: garment vertices (B, N, 3) m <-> descriptor S (B, 50). Vertices are
  taken relative to the template's mean shape and scaled by `shape_scale`; MLPs (`shape_widths`).
  Trained first, on every frame, with L2 + Laplacian (uniform, on the template's edges) losses.
- Motion encoder M_E: joint positions of the current and the past W frames (B, W + 1, 24, 3) m, in
  the current frame's character space -> c (B, 30): softplus, then unit norm (non-negative blend
  coefficients).
- Motion-invariant autoencoder F_E / F_D of U-blocks: a U-block is a linear layer whose weights are
  the c-weighted blend of 30 sub-layers, y = sum_k c_k (W_k x + b_k). F_E: (S, c) -> z (B, 100);
  F_D: (z, c) -> S'. Trained with M_E on batches that each hold frames of ONE intrinsic parameter
  set: Var(z in batch) + lambda * ||S - S'||^2 (S from the frozen shape encoder).

Use (`IntrinsicSpace.encode` / `.decode`): a keyframe's vertices and motion window -> z; z (per frame,
e.g. interpolated between keyframes) and each frame's motion window -> vertices in character space.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from drape.models.deepsd import mlp

NUM_JOINTS = 24


@dataclass(frozen=True)
class IntrinsicConfig:
    num_vertices: int
    window: int = 30  # W: past frames in the motion window (plus the current one)
    descriptor: int = 50
    latent: int = 100
    coefficients: int = 30
    shape_widths: tuple[int, ...] = (512, 256)
    motion_widths: tuple[int, ...] = (256, 128)
    invariant_widths: tuple[int, ...] = (128, 128)  # U-block hidden widths of F_E (F_D mirrors them)
    shape_scale: float = 10.0  # metres -> network units for the offsets from the mean shape

    def to_dict(self) -> dict:
        return asdict(self)


def character_space(points: torch.Tensor, root_position: torch.Tensor, root_rotation: torch.Tensor) -> torch.Tensor:
    """points (B, ..., 3) world m -> the character space of their frame: R^T (p - root_position).
    root_position (B, 3) m; root_rotation (B, 3, 3) the pelvis' global rotation."""
    shape = points.shape
    p = points.reshape(shape[0], -1, 3) - root_position[:, None, :]
    return (p @ root_rotation).reshape(shape)  # row vectors: p R == (R^T p^T)^T


def world_space(points: torch.Tensor, root_position: torch.Tensor, root_rotation: torch.Tensor) -> torch.Tensor:
    """The inverse of `character_space`: R p + root_position."""
    shape = points.shape
    p = points.reshape(shape[0], -1, 3) @ root_rotation.transpose(1, 2)
    return (p + root_position[:, None, :]).reshape(shape)


class ShapeAutoencoder(nn.Module):
    """N_E / N_D: vertices (B, N, 3) m in character space <-> descriptor (B, D)."""

    def __init__(self, cfg: IntrinsicConfig, mean_shape: torch.Tensor):
        super().__init__()
        self.scale = cfg.shape_scale
        self.num_vertices = cfg.num_vertices
        self.mean_shape: torch.Tensor
        self.register_buffer("mean_shape", mean_shape.reshape(1, -1).float().clone())
        n3 = 3 * cfg.num_vertices
        self.encoder = mlp([n3, *cfg.shape_widths, cfg.descriptor])
        self.decoder = mlp([cfg.descriptor, *cfg.shape_widths[::-1], n3])

    def encode(self, vertices: torch.Tensor) -> torch.Tensor:
        x = (vertices.flatten(1) - self.mean_shape) * self.scale  # flatten: the frame axis stays dynamic
        return self.encoder(x)

    def decode(self, descriptor: torch.Tensor) -> torch.Tensor:
        x = self.decoder(descriptor) / self.scale + self.mean_shape
        return x.reshape(-1, self.num_vertices, 3)


class MotionEncoder(nn.Module):
    """M_E: joint positions (B, W + 1, 24, 3) m, character space of the current frame -> (B, K), unit norm, >= 0."""

    def __init__(self, cfg: IntrinsicConfig):
        super().__init__()
        self.net = mlp([(cfg.window + 1) * NUM_JOINTS * 3, *cfg.motion_widths, cfg.coefficients])

    def forward(self, joints: torch.Tensor) -> torch.Tensor:
        c = nn.functional.softplus(self.net(joints.flatten(1)))
        return c / (c.norm(dim=1, keepdim=True) + 1e-8)


class UBlock(nn.Module):
    """y = sum_k c_k (W_k x + b_k): K sub-layers blended by the motion coefficients c (B, K)."""

    def __init__(self, c_in: int, c_out: int, k: int):
        super().__init__()
        self.c_out, self.k = c_out, k
        self.linear = nn.Linear(c_in, k * c_out)  # the K sub-layers side by side

    def forward(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        y = self.linear(x).reshape(-1, self.k, self.c_out)
        return (y * c.unsqueeze(-1)).sum(dim=1)


class UNet(nn.Module):
    """A stack of U-blocks with ELU between them: (B, in) x c (B, K) -> (B, out)."""

    def __init__(self, sizes: list[int], k: int):
        super().__init__()
        self.blocks = nn.ModuleList(UBlock(a, b, k) for a, b in zip(sizes[:-1], sizes[1:], strict=True))

    def forward(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        for i, block in enumerate(self.blocks):
            x = block(x, c)
            if i < len(self.blocks) - 1:
                x = nn.functional.elu(x)
        return x


class IntrinsicSpace(nn.Module):
    """The whole model of one template: N_E/N_D, M_E, F_E/F_D."""

    def __init__(self, cfg: IntrinsicConfig, mean_shape: torch.Tensor):
        super().__init__()
        self.cfg = cfg
        self.shape = ShapeAutoencoder(cfg, mean_shape)
        self.motion = MotionEncoder(cfg)
        widths = list(cfg.invariant_widths)
        self.f_encoder = UNet([cfg.descriptor, *widths, cfg.latent], cfg.coefficients)
        self.f_decoder = UNet([cfg.latent, *widths[::-1], cfg.descriptor], cfg.coefficients)

    def encode(self, vertices: torch.Tensor, window: torch.Tensor) -> torch.Tensor:
        """vertices (B, N, 3) and joint windows (B, W + 1, 24, 3), character space -> z (B, latent)."""
        return self.f_encoder(self.shape.encode(vertices), self.motion(window))

    def decode(self, z: torch.Tensor, window: torch.Tensor) -> torch.Tensor:
        """z (B, latent) and joint windows (B, W + 1, 24, 3) -> vertices (B, N, 3), character space."""
        return self.shape.decode(self.f_decoder(z, self.motion(window)))


class ShapeEncodeGraph(nn.Module):
    """The exported `shape_encode` (N_E): vertices (T, N, 3) m, character space -> descriptor (T, D)."""

    def __init__(self, model: IntrinsicSpace):
        super().__init__()
        self.model = model

    def forward(self, vertices: torch.Tensor) -> torch.Tensor:
        return self.model.shape.encode(vertices)


class ShapeDecodeGraph(nn.Module):
    """The exported `shape_decode` (N_D): descriptor (T, D) -> vertices (T, N, 3) m, character space."""

    def __init__(self, model: IntrinsicSpace):
        super().__init__()
        self.model = model

    def forward(self, descriptor: torch.Tensor) -> torch.Tensor:
        return self.model.shape.decode(descriptor)


class EncodeGraph(nn.Module):
    """The exported `encode` (M_E, F_E): descriptor (T, D), windows (T, W + 1, 24, 3) -> z (T, latent)."""

    def __init__(self, model: IntrinsicSpace):
        super().__init__()
        self.model = model

    def forward(self, descriptor: torch.Tensor, window: torch.Tensor) -> torch.Tensor:
        return self.model.f_encoder(descriptor, self.model.motion(window))


class DecodeGraph(nn.Module):
    """The exported `decode` (M_E, F_D): z (T, latent), windows (T, W + 1, 24, 3) -> descriptor (T, D)."""

    def __init__(self, model: IntrinsicSpace):
        super().__init__()
        self.model = model

    def forward(self, z: torch.Tensor, window: torch.Tensor) -> torch.Tensor:
        return self.model.f_decoder(z, self.model.motion(window))


def uniform_laplacian_loss(pred: torch.Tensor, target: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """Mean squared difference of uniform Laplacian coordinates (B, N, 3) over the template's edges (E, 2)."""
    n = pred.shape[1]
    deg = torch.zeros(n, dtype=pred.dtype).index_add_(0, edges.reshape(-1), torch.ones(edges.numel(), dtype=pred.dtype))

    def lap(x: torch.Tensor) -> torch.Tensor:
        s = torch.zeros_like(x)
        s = s.index_add(1, edges[:, 0], x[:, edges[:, 1]]).index_add(1, edges[:, 1], x[:, edges[:, 0]])
        return x - s / deg.clamp(min=1)[None, :, None]

    return ((lap(pred) - lap(target)) ** 2).sum(-1).mean()
