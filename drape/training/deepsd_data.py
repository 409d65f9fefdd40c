"""Training and evaluation data for DeePSD: generated outfits (cached) and pose pools.

Outfits are generated on demand and cached under data/deepsd/outfits/ (git-ignored,
reproducible from the config's seeds). Poses come from procedural motions and the
embedded clips minus the held-out ones; the root rotation and translation are
zeroed (physics losses are measured in the body's frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from drape.assets.body import load_body
from drape.assets.motion import list_clips, load_clip
from drape.assets.outfits import generate_outfit
from drape.assets.procedural import generate_motion
from drape.geometry.mesh import unique_edges
from drape.geometry.queries import (
    CANDIDATE_STRIDE,
    candidate_joints,
    loose_points,
    lowest_common_ancestor,
    nearest_vertex_weights,
)
from drape.runtime.deepsd import network_inputs

CACHE = Path("data/deepsd/outfits")


@dataclass(frozen=True)
class OutfitSpec:
    types: str
    vertices: int
    seed: int
    body: str
    looseness: float | None = None  # generate_outfit's; None: drawn from the seed in [0, 1]; > 1: oversize

    @property
    def key(self) -> str:
        loose = "" if self.looseness is None else f"_loose{self.looseness:.2f}"
        return f"{self.types.replace(',', '+')}_{self.vertices}_{self.seed}_{self.body}{loose}"


def train_specs(cfg: dict) -> list[OutfitSpec]:
    """The training outfits: `train_outfits` of `train_types` (seeds 1000 on), then, if the config has
    `train_oversize` ({"outfits", "types", "looseness": [lo, hi]}), that many oversize ones (seeds 5000 on):
    garments made for a larger body, their looseness drawn in [lo, hi] (generate_outfit: 2 leaves a ~60 mm gap
    to the body at the median, 3 ~80 mm; the ArcSim tops of ../shared/data/external fitted to the neutral body
    lie ~70 mm off it)."""
    rng = np.random.default_rng(cfg["seed"])
    lo, hi = cfg["train_vertices"]
    types, bodies = cfg["train_types"], cfg["bodies"]
    specs = [
        OutfitSpec(types[i % len(types)], int(rng.integers(lo, hi)), 1000 + i, bodies[i % len(bodies)])
        for i in range(cfg["train_outfits"])
    ]
    over: dict = cfg.get("train_oversize") or {}
    if over:
        loose_lo, loose_hi = over["looseness"]
        rng = np.random.default_rng([cfg["seed"], 5000])
        specs += [
            OutfitSpec(over["types"][i % len(over["types"])], int(rng.integers(lo, hi)), 5000 + i,
                       bodies[i % len(bodies)], round(float(rng.uniform(loose_lo, loose_hi)), 2))
            for i in range(over["outfits"])
        ]
    return specs


def eval_specs(cfg: dict) -> list[OutfitSpec]:
    """Held-out outfits: seeds never used in training, and combinations never trained on."""
    bodies = cfg["bodies"]
    return [
        OutfitSpec(t, cfg["eval_vertices"], 90000 + i, bodies[i % len(bodies)])
        for i, t in enumerate(cfg["eval_outfits"])
    ]


def load_outfit(spec: OutfitSpec) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3) float32, faces (F, 3) int32), generated once and cached under CACHE."""
    cache = CACHE
    path = cache / f"{spec.key}.npz"
    if path.exists():
        with np.load(path, allow_pickle=False) as z:
            return z["vertices"], z["faces"]
    o = generate_outfit(spec.types, vertices=spec.vertices, seed=spec.seed, body=spec.body, looseness=spec.looseness)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, vertices=o.vertices, faces=o.faces)
    tmp.replace(path)
    return o.vertices, o.faces


def _generate(spec: OutfitSpec) -> str:
    load_outfit(spec)
    return spec.key


def prepare_outfits(specs: list[OutfitSpec], workers: int | None = None) -> None:
    """Generate every missing outfit, in parallel (`workers`, default one per CPU core), with a progress bar."""
    import os
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    missing = [s for s in specs if not (CACHE / f"{s.key}.npz").exists()]
    if not missing:
        return
    with ProcessPoolExecutor(workers or os.cpu_count() or 1) as pool:
        for _ in tqdm(pool.map(_generate, missing), total=len(missing), desc="outfits"):
            pass


class TrainOutfit:
    """One outfit's tensors for training, built once. joint_candidates (a config's `joint_candidates`:
    keyword arguments of drape.geometry.queries.candidate_joints, e.g. {"influences": 4}): the weights are
    restricted to each vertex's candidate joints (`joint_mask` (N, 24) float 0/1, else None) and the prior
    weights to the same joints, renormalised."""

    def __init__(self, spec: OutfitSpec, joint_candidates: dict | None = None, loose_prior_share: float = 0.0):
        from drape.training.physics import BodyCollider

        v, f = load_outfit(spec)
        body = load_body(spec.body)
        inputs = network_inputs(v, f)
        self.spec = spec
        self.rest = torch.as_tensor(v)
        self.faces = torch.as_tensor(f, dtype=torch.int64)
        self.features = torch.as_tensor(inputs["features"])
        self.nbr_idx = torch.as_tensor(inputs["nbr_idx"])
        self.nbr_w = torch.as_tensor(inputs["nbr_w"])
        e = unique_edges(f)
        self.edges = torch.as_tensor(e)
        self.rest_len = (self.rest[self.edges[:, 0]] - self.rest[self.edges[:, 1]]).norm(dim=-1)
        prior = nearest_vertex_weights(v, body.vertices, body.weights)
        self.joint_mask: torch.Tensor | None = None
        if joint_candidates is not None:
            mask = candidate_joints(v, body.vertices, body.weights, parents=body.parents, **joint_candidates)
            prior = candidate_prior(prior, mask)
            beyond = joint_candidates.get("loose_beyond")
            if loose_prior_share > 0 and beyond is not None:
                loose = loose_points(v, body.vertices, beyond, joint_candidates.get("stride", CANDIDATE_STRIDE))
                prior = loose_ancestor_prior(prior, mask, loose, body.parents, loose_prior_share)
            self.joint_mask = torch.as_tensor(mask, dtype=torch.float32)
        self.prior_weights = torch.as_tensor(prior)
        self.joints = torch.as_tensor(body.joints)
        self.collider = BodyCollider(body, load_body(spec.body, proxy=True), v)
        identity = torch.zeros(1, 24, 3)
        from drape.training.physics import skinning_transforms

        rest = skinning_transforms(identity, self.joints)
        self.rest_distance = self.collider.signed_distance(self.rest[None], rest)[0]  # (N,) m

    def to(self, device: torch.device | str) -> TrainOutfit:
        """Move every tensor (and the collider's) to `device` (in place); returns self."""
        from drape.training.physics import move_tensors

        self.collider.to(device)
        return move_tensors(self, device)


def mocap_motion(directory: str | Path, name: str, fps: float, body: str = "neutral",
                 flips: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The real clip `directory/name.bvh` imported onto the `body` preset at `fps` (drape.assets.motion.import_motion:
    on the floor) -> (poses (T, 24, 3) rad, trans (T, 3) m) float32; cached under data/deepsd/mocap/ (git-ignored).

    Rotation flips (capture errors, drape.assets.motion_flips) are kept by default: the DeePSD and MGN models
    shipped before the importer repaired them (2026-11-30) were trained on the clips as they were, and their
    configs re-create that data. `flips=True` repairs them (cached apart)."""
    from drape.assets.motion import import_motion

    cache = CACHE.parent / "mocap" / f"{name}_{body}_{fps:g}{'_repaired' if flips else ''}.npz"
    if not cache.exists():
        path = Path(directory) / f"{name}.bvh"
        if not path.exists():
            raise FileNotFoundError(f"the config's mocap clip {path} is missing (../shared/data/mocap holds them)")
        motion = import_motion(path.read_bytes(), load_body(body), fps=fps, flips=flips, name=name).motion
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez(cache, poses=motion.poses, trans=motion.trans)
    with np.load(cache, allow_pickle=False) as z:
        return z["poses"].astype(np.float32), z["trans"].astype(np.float32)


def candidate_prior(prior: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """prior (N, K) weights, mask (N, K) bool candidate joints -> (N, K) float32: the prior restricted to the
    candidates and renormalised; a vertex whose prior lies wholly off its candidates (rare) takes them evenly."""
    out = prior * mask
    out = np.where(out.sum(1, keepdims=True) > 0, out, mask)
    return (out / out.sum(1, keepdims=True)).astype(np.float32)


def loose_ancestor_prior(prior: np.ndarray, mask: np.ndarray, loose: np.ndarray, parents: np.ndarray,
                         share: float) -> np.ndarray:
    """prior (N, K) weights (rows sum to 1), mask (N, K) bool candidate joints, loose (N,) bool, parents (K,)
    -> (N, K) float32: each loose vertex's prior moves `share` of its mass onto the lowest common ancestor of
    its candidate joints (the pelvis for a hem between the knees), the rest scaled by 1 - share; other rows
    unchanged. A prior that puts ~0 on that joint holds loose cloth on the legs (and a softmax weight near 0
    gets almost no gradient), though the candidates allow it."""
    out = np.array(prior, dtype=np.float32)
    rows = np.flatnonzero(loose)
    if len(rows) == 0:
        return out
    order = np.argsort(~mask[rows], axis=1, kind="stable")  # candidate joints first
    valid = np.take_along_axis(mask[rows], order, axis=1)
    ancestor = lowest_common_ancestor(parents, order, valid)
    out[rows] *= 1.0 - share
    out[rows, ancestor] += share
    return out


def mocap_poses(directory: str | Path, name: str, fps: float, flips: bool = False) -> np.ndarray:
    """(T, 24, 3) float32 poses of the real clip `directory/name.bvh` on the neutral body at `fps` (mocap_motion)."""
    return mocap_motion(directory, name, fps, flips=flips)[0]


def repairs_flips(mocap: dict) -> bool:
    """A config's `mocap` section -> whether its clips are read with their rotation flips repaired (`"flips"`:
    "keep", the default, or "repair"; drape.assets.motion_flips). ValueError for any other value."""
    if mocap.get("flips", "keep") not in ("keep", "repair"):
        raise ValueError(f"mocap.flips must be 'keep' or 'repair', got {mocap['flips']!r}")
    return mocap.get("flips") == "repair"


POSTURE_SEED_OFFSET = 1300  # procedural_posture's seeds: clear of the plain (500 on) and legs-apart (900 on) ones


def pose_pool(cfg: dict) -> np.ndarray:
    """(P, 24, 3) float32 training poses: procedural motions, legs-apart procedural motions
    (`procedural_spread`: {"motions", "spread"}, if any; generate_motion's `spread`), procedural motions with a
    captured skeleton's upper-back and clavicle posture (`procedural_posture`: {"motions", "posture"}, if any;
    generate_motion's `posture`, seeds seed + POSTURE_SEED_OFFSET on) + non-held-out clips +
    the config's real mocap clips (`mocap`: {"dir", "fps", "train": [names], "flips": "keep" (default) or
    "repair" (drape.assets.motion_flips)}, if any), root zeroed."""
    poses = []
    for i in range(cfg["procedural_motions"]):
        poses.append(generate_motion(cfg["procedural_frames"], seed=cfg["seed"] + 500 + i).poses)
    wide: dict = cfg.get("procedural_spread") or {}
    for i in range(wide.get("motions", 0)):
        poses.append(generate_motion(cfg["procedural_frames"], seed=cfg["seed"] + 900 + i,
                                     spread=float(wide["spread"])).poses)
    posture: dict = cfg.get("procedural_posture") or {}
    for i in range(posture.get("motions", 0)):
        poses.append(generate_motion(cfg["procedural_frames"], seed=cfg["seed"] + POSTURE_SEED_OFFSET + i,
                                     posture=float(posture["posture"])).poses)
    for name in list_clips():
        if name not in cfg["heldout_clips"]:
            poses.append(load_clip(name).poses)
    mocap: dict = cfg.get("mocap") or {}
    repair = repairs_flips(mocap)
    for name in mocap.get("train", []):
        poses.append(mocap_poses(mocap["dir"], name, mocap["fps"], flips=repair))
    pool = np.concatenate(poses).astype(np.float32)
    pool[:, 0] = 0.0
    return pool
