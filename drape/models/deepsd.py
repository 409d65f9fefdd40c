"""DeePSD (Bertiche et al., ICCV 2021): outfit -> blend weights + pose-space blend shapes.

Outfit network, per template outfit (any topology, any vertex count N):
  input per vertex: rest position + normal (N, 6), metres;
  4 graph convolutions (32, 64, 128, 256) over the padded neighbour table
  (gather + weighted sum: ONNX-safe, no scatter);
  a per-vertex FC + max-pool -> global descriptor (256), concatenated per vertex (512);
  heads (4-layer per-vertex MLPs): Omega -> blend weights W (N, 24) (softmax; with a joint mask (N, 24),
  over each vertex's candidate joints only: drape.geometry.queries.candidate_joints),
  Psi -> D_data (P, N, 3), Chi -> D_phys (P, N, 3) (trained by physics only).
  Deployed blend shapes D = D_data + D_phys.
Pose network: axis-angle pose (T, 72) -> P pose keys (T, P), summing to 1 (softmax);
the root orientation is ignored (pose-space deformation depends on the joints only).
Posed vertices: V = LBS(T + sum_p keys_p D_p, J, theta, W).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

NUM_JOINTS = 24


@dataclass(frozen=True)
class DeePSDConfig:
    conv_widths: tuple[int, ...] = (32, 64, 128, 256)
    global_width: int = 256
    head_width: int = 256
    num_keys: int = 128  # P
    pose_width: int = 256
    blend_scale: float = 0.05  # metres: D heads output tanh-free, scaled so init offsets stay small

    def to_dict(self) -> dict:
        return asdict(self)


class GraphConv(nn.Module):
    """x_i' = act(A x_i + B mean_{j in N(i)} x_j): neighbours from a padded (N, K) table + weights."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.self_lin = nn.Linear(c_in, c_out)
        self.nbr_lin = nn.Linear(c_in, c_out, bias=False)

    def forward(self, x: torch.Tensor, nbr_idx: torch.Tensor, nbr_w: torch.Tensor) -> torch.Tensor:
        # x (N, C); nbr_idx (N, K) int64; nbr_w (N, K) float -> (N, C_out)
        gathered = x[nbr_idx]  # (N, K, C)
        mean = (gathered * nbr_w.unsqueeze(-1)).sum(dim=1)
        return torch.nn.functional.elu(self.self_lin(x) + self.nbr_lin(mean))


def mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ELU())
    return nn.Sequential(*layers)


def masked_softmax(logits: torch.Tensor, joint_mask: torch.Tensor | None) -> torch.Tensor:
    """(N, 24) logits -> weights summing to 1 over the joints where joint_mask (N, 24) float 0/1 is 1 (all
    joints when None); the others get exactly 0 in float32 (exp(-1e4) underflows)."""
    if joint_mask is None:
        return torch.softmax(logits, dim=-1)
    return torch.softmax(logits + (joint_mask - 1.0) * 1e4, dim=-1)


class OutfitNet(nn.Module):
    """(features (N, 6), nbr_idx (N, K), nbr_w (N, K)[, joint_mask (N, 24)]) -> (W (N, 24), D_data (P, N, 3),
    D_phys (P, N, 3))."""

    def __init__(self, cfg: DeePSDConfig = DeePSDConfig()):
        super().__init__()
        self.cfg = cfg
        widths = (6,) + tuple(cfg.conv_widths)
        self.convs = nn.ModuleList(GraphConv(a, b) for a, b in zip(widths[:-1], widths[1:], strict=True))
        c = widths[-1]
        self.global_fc = nn.Linear(c, cfg.global_width)
        feat = c + cfg.global_width
        h = cfg.head_width
        self.omega = mlp([feat, h, h, h, NUM_JOINTS])
        self.psi = mlp([feat, h, h, h, cfg.num_keys * 3])
        self.chi = mlp([feat, h, h, h, cfg.num_keys * 3])

    def features(self, x: torch.Tensor, nbr_idx: torch.Tensor, nbr_w: torch.Tensor) -> torch.Tensor:
        for conv in self.convs:
            x = conv(x, nbr_idx, nbr_w)
        g = torch.nn.functional.elu(self.global_fc(x)).amax(dim=0, keepdim=True)  # (1, G)
        return torch.cat([x, g.expand(x.shape[0], -1)], dim=1)

    def _blend(self, head: nn.Module, f: torch.Tensor) -> torch.Tensor:
        n = f.shape[0]
        return (head(f) * self.cfg.blend_scale).reshape(n, self.cfg.num_keys, 3).permute(1, 0, 2)

    def forward(
        self, x: torch.Tensor, nbr_idx: torch.Tensor, nbr_w: torch.Tensor, joint_mask: torch.Tensor | None = None,
        chi: bool = True,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """chi=False skips the Chi head (D_phys None): training phases that do not use it."""
        f = self.features(x, nbr_idx, nbr_w)
        weights = masked_softmax(self.omega(f), joint_mask)
        return weights, self._blend(self.psi, f), self._blend(self.chi, f) if chi else None


class DeployedOutfitNet(nn.Module):
    """The exported form: (features, nbr_idx, nbr_w) -> (W (N, 24), D = D_data + D_phys (P, N, 3), D_data).

    D_data alone is kept as a third output for evaluating the model without Chi.
    """

    def __init__(self, net: OutfitNet):
        super().__init__()
        self.net = net

    def forward(
        self, x: torch.Tensor, nbr_idx: torch.Tensor, nbr_w: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        w, d_data, d_phys = self.net(x, nbr_idx, nbr_w)
        assert d_phys is not None
        return w, d_data + d_phys, d_data


class DeployedMaskedOutfitNet(nn.Module):
    """DeployedOutfitNet with a fourth input, joint_mask (N, 24) float32 0/1: each vertex's candidate joints
    (drape.geometry.queries.candidate_joints of the body it is rigged on); W is 0 off them."""

    def __init__(self, net: OutfitNet):
        super().__init__()
        self.net = net

    def forward(
        self, x: torch.Tensor, nbr_idx: torch.Tensor, nbr_w: torch.Tensor, joint_mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        w, d_data, d_phys = self.net(x, nbr_idx, nbr_w, joint_mask)
        assert d_phys is not None
        return w, d_data + d_phys, d_data


class PoseNet(nn.Module):
    """Axis-angle poses (T, 72) radians -> pose keys (T, P) >= 0 summing to 1."""

    def __init__(self, cfg: DeePSDConfig = DeePSDConfig()):
        super().__init__()
        w = cfg.pose_width
        self.net = mlp([(NUM_JOINTS - 1) * 3, w, w, w, cfg.num_keys])

    def forward(self, poses: torch.Tensor) -> torch.Tensor:
        # the root orientation (first 3 values) is ignored: pose-space deformation is local
        return torch.softmax(self.net(poses[:, 3:]), dim=-1)


def outfit_features(vertices: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """(N, 3) rest positions (m) and unit normals -> (N, 6) network input."""
    return torch.cat([vertices, normals], dim=1)
