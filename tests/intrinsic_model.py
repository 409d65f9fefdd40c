"""A small random-init intrinsic garment model (a generated skirt of ~300 vertices on the neutral body), exported
once per test session into a temporary intrinsic_dir: the runtime and service tests serve it."""

from __future__ import annotations

import functools
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.export.intrinsic import export_intrinsic
from drape.geometry.character_space import motion_windows, root_frames
from drape.models.intrinsic import IntrinsicConfig, IntrinsicSpace

NAME = "testskirt"
WINDOW = 8
LATENT = 100  # the paper's size: the API's examples (latents of 100 values) then reach the model


@dataclass(frozen=True)
class TestGarment:
    """The torch model, the intrinsic_dir (root) holding its folder (path), the template vertices (N, 3) m in
    rest pose on the neutral body and faces (F, 3)."""

    model: IntrinsicSpace
    root: Path
    path: Path
    vertices: np.ndarray
    faces: np.ndarray


@functools.cache
def intrinsic_model() -> TestGarment:
    torch.manual_seed(21)
    outfit = generate_outfit("skirt", vertices=300, seed=3, length=0.6)
    body = load_body("neutral")
    rest = outfit.vertices.astype(np.float64)
    mean_shape = rest - body.joints[0]  # the template in the character space of the rest pose
    cfg = IntrinsicConfig(num_vertices=len(rest), window=WINDOW, descriptor=16, latent=LATENT, coefficients=8,
                          shape_widths=(64,), motion_widths=(32,), invariant_widths=(32,))
    model = IntrinsicSpace(cfg, torch.as_tensor(mean_shape, dtype=torch.float32)).eval()
    with torch.no_grad():  # a plain random init moves its shapes by < 0.1 mm with the latent or the motion
        model.motion.net[0].weight.mul_(10.0)  # window: now cm, so that the tests' 1e-4 m tolerances discriminate
        for p in [*model.f_encoder.parameters(), *model.f_decoder.parameters()]:
            p.mul_(3.0)
    clip = load_clip("walk")
    joints, rp, rr = root_frames(clip.poses[:40].astype(np.float64), clip.trans[:40].astype(np.float64),
                                 body.joints.astype(np.float64), body.parents)
    windows = torch.as_tensor(motion_windows(joints, rp, rr, WINDOW))
    shapes = torch.as_tensor(mean_shape, dtype=torch.float32)[None].expand(len(windows), -1, -1)
    with torch.no_grad():
        z = model.encode(shapes, windows).numpy()  # the template's latents under 40 motion windows
    root = Path(tempfile.mkdtemp(prefix="drape-intrinsic-"))
    export_intrinsic(model, root / NAME, template=NAME, rest_vertices=rest, faces=outfit.faces, body="neutral",
                     fps=30.0, latent_mean=z.mean(0), latent_std=np.maximum(z.std(0), 1e-2))
    return TestGarment(model, root, root / NAME, outfit.vertices, outfit.faces)
