"""How long one DeePSD physics-phase training step takes on this machine, with the body collider as served to training
(`physics.nearest_points`: a KD-tree per frame; the body's normals by one sparse product, `physics.face_incidence`)
against the collider as it was before 2026-12-02 (the (B, N, G) distance matrix's argmin to the collision proxy; the
normals by three scatters), in the same run.

A step is what `drape train deepsd` runs in its physics phase: one training outfit x `batch_frames` poses of the
config's pool, forward, loss, backward, Adam. The outfits are the first `--outfits` of the config's training list
(generated and cached as training does), the networks fresh (seed 0), the same outfits and poses for both variants.
The nearest proxy vertex of each garment vertex is checked to be the same in both (ties aside).

Output: ms a step for each variant (median of the timed steps), the collider's share of it, and the ratio.

Run: PYTHONPATH=. .venv/bin/python -m bench.deepsd_step [--config PATH] [--outfits 6] [--steps 24]
(about 1 min on the 2-core machine, otherwise idle)
"""

from __future__ import annotations

import argparse
import time
from contextlib import contextmanager

import numpy as np
import torch

from drape.models.deepsd import DeePSDConfig, OutfitNet, PoseNet
from drape.training import DEFAULT_DEEPSD_CONFIG, physics
from drape.training import deepsd as training
from drape.training.deepsd_data import TrainOutfit, pose_pool, prepare_outfits, train_specs


def distance_matrix_nearest(queries: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """The collider's nearest proxy vertex before: (B, N, 3), (B, G, 3) -> (B, N), argmin of the (B, N, G) matrix."""
    return torch.cdist(queries, points).argmin(dim=-1)


@contextmanager
def collider_before(outfits: list[TrainOutfit]):
    """The collider as it was: the distance matrix's argmin, the normals by scatters (no incidence)."""
    saved = physics.nearest_points
    kept = [o.collider.incidence for o in outfits]
    physics.nearest_points = distance_matrix_nearest
    for o in outfits:
        o.collider.incidence = None
    try:
        yield
    finally:
        physics.nearest_points = saved
        for o, inc in zip(outfits, kept, strict=True):
            o.collider.incidence = inc


def time_steps(cfg: dict, outfits: list[TrainOutfit], pool: torch.Tensor, steps: int) -> tuple[float, float]:
    """Median ms of a physics step and of its collider call, over `steps` steps after 3 untimed ones."""
    torch.manual_seed(0)
    net, pose = OutfitNet(DeePSDConfig()), PoseNet(DeePSDConfig())
    lw = training.phase_loss_weights(cfg, "physics")
    opt = torch.optim.Adam(training._trainable("physics", net, pose), lr=cfg["lr"])
    collider_s: list[float] = []
    for o in outfits:
        inner = o.collider.signed_distance

        def timed(garment, transforms, inner=inner):
            t0 = time.perf_counter()
            out = inner(garment, transforms)
            collider_s.append(time.perf_counter() - t0)
            return out

        o.collider.signed_distance = timed
    step_s = []
    try:
        for i in range(steps + 3):
            rng = np.random.default_rng([cfg["seed"], 1, i])
            outfit = outfits[i % len(outfits)]
            poses = pool[torch.as_tensor(rng.integers(len(pool), size=cfg["batch_frames"]))]
            t0 = time.perf_counter()
            loss, _ = training.step_loss("physics", outfit, poses, net, pose, lw)
            opt.zero_grad()
            loss.backward()
            opt.step()
            step_s.append(time.perf_counter() - t0)
    finally:
        for o in outfits:
            del o.collider.signed_distance  # the instance attribute: the class's method again
    return float(np.median(step_s[3:])) * 1e3, float(np.median(collider_s[3:])) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=str(DEFAULT_DEEPSD_CONFIG))
    ap.add_argument("--outfits", type=int, default=6)
    ap.add_argument("--steps", type=int, default=24)
    args = ap.parse_args()
    cfg = training.load_config(args.config)
    specs = train_specs(cfg)[:args.outfits]
    prepare_outfits(specs)
    outfits = [TrainOutfit(s, cfg.get("joint_candidates"), cfg.get("loose_prior_share", 0.0)) for s in specs]
    pool = torch.as_tensor(pose_pool(cfg))
    sizes = [len(o.rest) for o in outfits]
    print(f"{len(outfits)} training outfits ({min(sizes)}-{max(sizes)} vertices), batch {cfg['batch_frames']} poses, "
          f"{torch.get_num_threads()} threads")

    # the same nearest proxy vertices both ways, on one batch of every outfit
    with torch.no_grad():
        for o in outfits:
            tr = physics.skinning_transforms(pool[:cfg["batch_frames"]], o.joints)
            garment = physics.lbs(o.rest, o.prior_weights, tr)
            proxy = physics.lbs(o.collider.proxy_rest, o.collider.proxy_weights, tr)
            same = (physics.nearest_points(garment, proxy) == distance_matrix_nearest(garment, proxy)).float().mean()
            assert float(same) > 0.999, f"nearest proxy vertices differ on {1 - float(same):.2%}"

    now_step, now_coll = time_steps(cfg, outfits, pool, args.steps)
    with collider_before(outfits):
        old_step, old_coll = time_steps(cfg, outfits, pool, args.steps)
    print("| collider | ms a step | the collider's ms |\n| --- | --: | --: |")
    print(f"| before (distance matrix, scattered normals) | {old_step:.1f} | {old_coll:.1f} |")
    print(f"| served to training (KD-tree, sparse normals) | {now_step:.1f} | {now_coll:.1f} |")
    print(f"step {old_step / now_step:.2f}x faster, the collider {old_coll / now_coll:.2f}x")


if __name__ == "__main__":
    main()
