"""Differentiable posing and the physics losses of DeePSD / PBNS (torch).

Shapes: B frames, N garment vertices, M body vertices, K = 24 joints. Metres.
"""

from __future__ import annotations

import numpy as np
import torch

from drape.geometry.skeleton import PARENTS


def axis_angle_to_matrix(aa: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3), Rodrigues."""
    angle = aa.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    axis = aa / angle
    x, y, z = axis.unbind(-1)
    zero = torch.zeros_like(x)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(aa.shape[:-1] + (3, 3))
    s = torch.sin(angle)[..., None]
    c = torch.cos(angle)[..., None]
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand_as(k)
    return eye + s * k + (1 - c) * (k @ k)


def skinning_transforms(poses: torch.Tensor, rest_joints: torch.Tensor) -> torch.Tensor:
    """poses (B, 24, 3), rest_joints (24, 3) -> (B, 24, 3, 4) affine transforms rest -> posed (no translation)."""
    rot = axis_angle_to_matrix(poses)
    glob_r: list[torch.Tensor] = []
    glob_t: list[torch.Tensor] = []
    for k in range(24):
        p = int(PARENTS[k])
        if p < 0:
            glob_r.append(rot[:, k])
            glob_t.append(rest_joints[k].expand(poses.shape[0], 3))
        else:
            glob_r.append(glob_r[p] @ rot[:, k])
            glob_t.append(glob_t[p] + (glob_r[p] @ (rest_joints[k] - rest_joints[p]))[..., :])
    r = torch.stack(glob_r, dim=1)
    t = torch.stack(glob_t, dim=1) - (r @ rest_joints[None, :, :, None])[..., 0]
    return torch.cat([r, t[..., None]], dim=-1)


def lbs(rest: torch.Tensor, weights: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
    """rest (N, 3) or (B, N, 3), weights (N, 24), transforms (B, 24, 3, 4) -> (B, N, 3)."""
    blended = torch.einsum("nk,bkij->bnij", weights, transforms)
    if rest.dim() == 2:
        rest = rest.expand(transforms.shape[0], -1, -1)
    return (blended[..., :3] @ rest[..., None])[..., 0] + blended[..., 3]


def vertex_normals(v: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(B, N, 3), (F, 3) -> (B, N, 3) area-weighted unit normals."""
    fn = torch.cross(v[:, faces[:, 1]] - v[:, faces[:, 0]], v[:, faces[:, 2]] - v[:, faces[:, 0]], dim=-1)
    vn = torch.zeros_like(v)
    for c in range(3):
        vn = vn.index_add(1, faces[:, c], fn)
    return vn / vn.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def edge_lengths(v: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """v (B, N, 3) m, edges (E, 2) -> lengths (B, E) m."""
    return (v[:, edges[:, 0]] - v[:, edges[:, 1]]).norm(dim=-1)


def edge_loss(v: torch.Tensor, edges: torch.Tensor, rest_len: torch.Tensor) -> torch.Tensor:
    """Mean |edge length - template length| (m)."""
    return (edge_lengths(v, edges) - rest_len).abs().mean()


def bending_loss(v: torch.Tensor, faces: torch.Tensor, nbr_idx: torch.Tensor, nbr_w: torch.Tensor) -> torch.Tensor:
    """Mean squared uniform Laplacian of the vertex normals (smooth normals = little bending)."""
    n = vertex_normals(v, faces)
    mean = (n[:, nbr_idx] * nbr_w[None, ..., None]).sum(dim=2)
    return ((n - mean) ** 2).sum(dim=-1).mean()


def move_tensors(obj, device: torch.device | str):  # noqa: ANN001, ANN201
    """Move every tensor attribute of `obj` to `device` (in place); returns obj."""
    for name, value in vars(obj).items():
        if isinstance(value, torch.Tensor):
            setattr(obj, name, value.to(device))
    return obj


class BodyCollider:
    """Signed distance of garment vertices to the posed body, DeePSD style.

    The nearest posed body vertex is searched among candidates: the garment
    vertex's nearest body vertices at rest, plus the full-body neighbourhood of
    its nearest posed collision-proxy vertex (which catches contacts that the
    rest pose did not have, e.g. a sleeve against the torso).
    """

    def __init__(self, body, proxy, garment_rest: np.ndarray, k_rest: int = 24, k_proxy: int = 16):
        from scipy.spatial import cKDTree

        self.faces = torch.as_tensor(body.faces, dtype=torch.int64)
        self.rest = torch.as_tensor(body.vertices, dtype=torch.float32)
        self.weights = torch.as_tensor(body.weights, dtype=torch.float32)
        self.joints = torch.as_tensor(body.joints, dtype=torch.float32)
        self.proxy_rest = torch.as_tensor(proxy.vertices, dtype=torch.float32)
        self.proxy_weights = torch.as_tensor(proxy.weights, dtype=torch.float32)
        tree = cKDTree(body.vertices)
        self.rest_cand = torch.as_tensor(tree.query(garment_rest, k=k_rest)[1], dtype=torch.int64)  # (N, k)
        self.proxy_nbrs = torch.as_tensor(tree.query(proxy.vertices, k=k_proxy)[1], dtype=torch.int64)  # (G, k)

    def to(self, device: torch.device | str) -> BodyCollider:
        """Move every tensor to `device` (in place); returns self."""
        return move_tensors(self, device)

    def signed_distance(self, garment: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
        """garment (B, N, 3) posed; transforms (B, 24, 3, 4) -> (B, N) metres (negative inside)."""
        with torch.no_grad():
            body = lbs(self.rest, self.weights, transforms)
            normals = vertex_normals(body, self.faces)
            proxy = lbs(self.proxy_rest, self.proxy_weights, transforms)
            near_proxy = torch.cdist(garment.detach(), proxy).argmin(dim=-1)  # (B, N)
            cand = torch.cat([self.rest_cand.expand(garment.shape[0], -1, -1), self.proxy_nbrs[near_proxy]], dim=-1)
            bidx = torch.arange(garment.shape[0], device=garment.device)[:, None, None]
            d2 = ((body[bidx, cand] - garment.detach()[:, :, None]) ** 2).sum(-1)
            nearest = cand.gather(2, d2.argmin(-1, keepdim=True))[..., 0]  # (B, N)
            b = torch.arange(garment.shape[0], device=garment.device)[:, None]
            p, n = body[b, nearest], normals[b, nearest]
        return ((garment - p) * n).sum(dim=-1)


def collision_loss(sd: torch.Tensor, eps: float) -> torch.Tensor:
    """Mean penetration below the margin eps (m): relu(eps - sd)."""
    return torch.relu(eps - sd).mean()
