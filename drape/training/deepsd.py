"""`drape train deepsd`: DeePSD trained by physics on generated outfits and motions.

Three phases, each a number of steps of one outfit x `batch_frames` poses:

1. prior (the paper's first epoch): blend weights -> the nearest body vertex's
   weights, blend shapes -> small;
2. physics: Omega, Psi, the pose network and the graph layers, by the physics
   losses (edge length vs template, bending, collision with a 5 mm margin, L2 on
   D) on poses from the training motions, plus a "follow" term (no vertex drifts
   more than a margin farther from the body than at rest) and a weak pull of the
   weights toward the prior: physics alone is also satisfied by a rigid garment
   that stops following the body. Psi learns "prior + physics" here (no
   simulated ground truth yet);
3. chi: Chi alone, by the physics losses only, on augmented poses (training
   poses plus noise), the rest frozen.

Checkpoints go to `checkpoints/deepsd/` (git-ignored); a rerun resumes from the
latest one (of the same config: another one's checkpoints are refused, `validation` aside; and of the same data:
`training_data` is recorded in every checkpoint, and a pose pool or outfit list changed since, e.g. an embedded
clip added, is refused too). The run is seeded; the config is recorded in every checkpoint.
A config with `"init_checkpoints": DIR` is a fine-tune: a fresh run starts from the
networks of DIR's latest checkpoint (a finished run of another config) instead of
random weights; phases with 0 steps are skipped. `"loss_phase": {PHASE: {NAME: WEIGHT}}` overrides
loss weights in one phase only (e.g. a stiffer edge term for the physics phase than for Chi).
`"joint_candidates": {...}` (keyword arguments of drape.geometry.queries.candidate_joints) restricts every
vertex's weights to at most `influences` joints of the body's skin near it, by construction (the export then
takes a joint_mask input, and the served 4-influence rig is the network's own). `"loose_prior_share": s` (with
`joint_candidates.loose_beyond`) gives the candidates' common ancestor s of the weights prior of every vertex
beyond that distance (drape.training.deepsd_data.loose_ancestor_prior); absent or 0: the prior as before.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np
import torch

from drape.models.deepsd import DeePSDConfig, OutfitNet, PoseNet
from drape.training import DEFAULT_DEEPSD_CONFIG as DEFAULT_CONFIG
from drape.training import physics
from drape.training.config_file import read_config
from drape.training.deepsd_data import (
    OutfitSpec,
    TrainOutfit,
    pose_pool,
    prepare_outfits,
    train_specs,
)
from drape.training.validated_steps import check_same_config, check_same_data, save_whole

PHASES = ("prior", "physics", "chi")


def load_config(path: str | Path = DEFAULT_CONFIG) -> dict:
    return read_config(path, "deepsd")


def _trainable(phase: str, net: OutfitNet, pose: PoseNet) -> list[torch.nn.Parameter]:
    if phase == "chi":
        return list(net.chi.parameters())
    chi = {id(p) for p in net.chi.parameters()}
    return [p for p in net.parameters() if id(p) not in chi] + list(pose.parameters())


def phase_loss_weights(cfg: dict, phase: str) -> dict:
    """The config's `loss` weights, with the phase's entries of `loss_phase` (if any) on top.

    A phase or loss name that does not exist is an error, not a silently ignored override.
    """
    overrides = cfg.get("loss_phase", {})
    for name, weights in overrides.items():
        if name not in PHASES:
            raise ValueError(f"loss_phase: unknown phase {name!r} (phases: {', '.join(PHASES)})")
        unknown = sorted(set(weights) - set(cfg["loss"]))
        if unknown:
            raise ValueError(f"loss_phase.{name}: unknown loss weights {unknown} (not in `loss`)")
    return {**cfg["loss"], **overrides.get(phase, {})}


def step_loss(phase: str, outfit: TrainOutfit, poses: torch.Tensor, net: OutfitNet, pose: PoseNet,
              lw: dict) -> tuple[torch.Tensor, dict[str, float]]:
    """Loss of one outfit under a batch of poses (B, 24, 3) for the given phase; lw: that phase's
    loss weights (`phase_loss_weights`)."""
    # the physics phase trains D_data alone: Chi's head is not run
    weights, d_data, d_phys = net(outfit.features, outfit.nbr_idx, outfit.nbr_w, outfit.joint_mask,
                                  chi=phase != "physics")
    if phase == "prior":
        assert d_phys is not None
        l_w = ((weights - outfit.prior_weights) ** 2).sum(-1).mean()
        l_d = (d_data**2).sum(-1).mean() + (d_phys**2).sum(-1).mean()
        loss = lw["prior_weights"] * l_w + lw["prior_blend"] * l_d
        return loss, {"prior_w": float(l_w.detach()), "prior_d": float(l_d.detach())}
    blend = d_data + d_phys if d_phys is not None else d_data
    keys = pose(poses.reshape(len(poses), -1))
    offsets = torch.einsum("bp,pnc->bnc", keys, blend)
    transforms = physics.skinning_transforms(poses, outfit.joints)
    v = physics.lbs(outfit.rest + offsets, weights, transforms)
    l_edge = physics.edge_loss(v, outfit.edges, outfit.rest_len)
    l_bend = physics.bending_loss(v, outfit.faces, outfit.nbr_idx, outfit.nbr_w)
    sd = outfit.collider.signed_distance(v, transforms)
    l_coll = physics.collision_loss(sd, lw["eps"])
    l_d = (blend**2).sum(-1).mean()
    # cloth hangs on the body: a vertex may not drift farther from it than at rest (+ margin);
    # without this, a garment that stops following the body has no stretch and no collision
    l_follow = torch.relu(sd - outfit.rest_distance - lw["follow_margin"]).mean()
    l_prior_v = ((weights - outfit.prior_weights) ** 2).sum(-1)  # (N,)
    l_prior = l_prior_v.mean()
    # optional: cloth that lies on the skin at rest keeps the skin's weights more strongly
    # (weight * exp(-rest distance / scale)); loose cloth is left to the physics
    near = lw.get("prior_weights_near")
    l_near = ((l_prior_v * torch.exp(-outfit.rest_distance.clamp_min(0) / near["scale"])).mean()
              * near["weight"]) if near else torch.zeros(())
    loss = 1e3 * (lw["edge"] * l_edge + lw["bend"] * l_bend + lw["collision"] * l_coll + lw["blend_l2"] * l_d
                  + lw["follow"] * l_follow) + lw["prior_weights_physics"] * l_prior + l_near
    stats = {"follow_mm": float(l_follow.detach()) * 1e3, "edge_mm": float(l_edge.detach()) * 1e3, "inside": float((sd < 0).float().mean()),
             "bend": float(l_bend.detach())}
    return loss, stats


def _latest(ckpt_dir: Path) -> Path | None:
    found = sorted(ckpt_dir.glob("step_*.pt"))
    return found[-1] if found else None


def training_device(name: str = "auto") -> torch.device:
    """`auto`: the CUDA GPU when torch sees one, else the CPU; or `cpu` / `cuda` / `cuda:N` as named."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    return torch.device(name)


def _to_cpu(value):
    """A checkpoint's nested dicts / lists of tensors, every tensor on the CPU (checkpoints load anywhere)."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, dict):
        return {k: _to_cpu(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_to_cpu(v) for v in value)
    return value


def training_data(specs: list[OutfitSpec], pool: np.ndarray) -> dict[str, list[str]]:
    """What a run trains on, as its checkpoints record it (validated_steps.check_same_data): the outfits' keys and
    the pose pool (P, 24, 3) by its size and content hash. The config names both, but the pool also takes every
    embedded clip not held out and the mocap files' contents, which may change under the same config."""
    digest = hashlib.sha256(np.ascontiguousarray(pool, dtype="<f4").tobytes()).hexdigest()[:16]
    return {"outfits": [s.key for s in specs], "pose_pool": [f"{len(pool)} poses sha256:{digest}"]}


def train(config: dict, ckpt_dir: str | Path = "checkpoints/deepsd", log=print,
          device: str = "auto") -> tuple[OutfitNet, PoseNet, dict]:
    """Train (or resume) and return the networks (on the CPU) and a summary. `device`: where the steps run
    (`training_device`); the recipe and its random draws are the same on every device, the arithmetic is not
    bit-identical between CPU and GPU."""
    from tqdm import tqdm

    torch.set_num_threads(max(1, torch.get_num_threads()))
    dev = training_device(device)
    ckpt_dir = Path(ckpt_dir)
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(config["seed"])
    net, pose = OutfitNet(DeePSDConfig()), PoseNet(DeePSDConfig())
    done = {p: 0 for p in PHASES}
    elapsed = 0.0
    latest = _latest(ckpt_dir)
    state = None
    ran_on = None
    if latest is not None:
        state = torch.load(latest, weights_only=True, map_location="cpu")
        # the checkpoint choice (`validation`) runs after training: a rerun may change it and keep the checkpoints
        check_same_config({k: v for k, v in json.loads(state["config"]).items() if k != "validation"},
                          {k: v for k, v in config.items() if k != "validation"}, latest)
        net.load_state_dict(state["outfit"])
        pose.load_state_dict(state["pose"])
        done = dict(zip(PHASES, state["done"].tolist(), strict=True))
        elapsed = float(state["elapsed"])
        log(f"resuming from {latest.name}: {done}")
        ran_on = state.get("device", "unknown")  # where the steps so far ran (older checkpoints: unknown)
    elif config.get("init_checkpoints"):
        base = _latest(Path(config["init_checkpoints"]))
        if base is None:
            raise FileNotFoundError(f"init_checkpoints: no step_*.pt in {config['init_checkpoints']}")
        init = torch.load(base, weights_only=True, map_location="cpu")
        net.load_state_dict(init["outfit"])
        pose.load_state_dict(init["pose"])
        log(f"fine-tuning from {base} ({float(init['elapsed']):.0f} s of training)")
    # checked before the outfits are prepared: a misspelt override fails at once, not minutes in
    loss_weights = {p: phase_loss_weights(config, p) for p in PHASES}
    specs = train_specs(config)
    pool_array = pose_pool(config)
    data = training_data(specs, pool_array)
    if state is not None and latest is not None:
        if "data" in state:
            check_same_data(json.loads(state["data"]), data, latest)
        else:  # saved before checkpoints recorded their data: taken, the checkpoints from here on record it
            log(f"{latest.name} does not record the data it was trained on (an older checkpoint): resuming "
                "without checking it")
    prepare_outfits(specs)
    outfits = [TrainOutfit(s, config.get("joint_candidates"), config.get("loose_prior_share", 0.0)).to(dev) for s in specs]
    pool = torch.as_tensor(pool_array).to(dev)
    net.to(dev)
    pose.to(dev)
    log(f"training on {dev}")
    summary: dict = {"phases": {}}
    if config.get("init_checkpoints"):
        summary["init_checkpoints"] = config["init_checkpoints"]
    for phase in PHASES:
        total = int(config["steps"][phase])
        if done[phase] >= total:
            continue
        ran_on = str(dev)
        params = _trainable(phase, net, pose)
        opt = torch.optim.Adam(params, lr=config["lr"])
        if state is not None and state.get("opt_phase") == phase:
            opt.load_state_dict(state["opt"])
        for p in net.parameters():
            p.requires_grad_(False)
        for p in pose.parameters():
            p.requires_grad_(False)
        for p in params:
            p.requires_grad_(True)
        bar = tqdm(range(done[phase], total), desc=phase, initial=done[phase], total=total)
        t0 = time.time()
        for step in bar:
            rng = np.random.default_rng([config["seed"], PHASES.index(phase), step])
            outfit = outfits[int(rng.integers(len(outfits)))]
            poses = pool[torch.as_tensor(rng.integers(len(pool), size=config["batch_frames"]), device=dev)]
            if phase == "chi":
                noise = torch.as_tensor(rng.normal(0, config["pose_noise"], poses.shape), dtype=torch.float32,
                                        device=dev)
                noise[:, 0] = 0.0
                poses = poses + noise
            loss, stats = step_loss(phase, outfit, poses, net, pose, loss_weights[phase])
            opt.zero_grad()
            loss.backward()
            opt.step()
            bar.set_postfix({k: round(v, 4) for k, v in stats.items()}, refresh=False)
            done[phase] = step + 1
            if done[phase] % config["checkpoint_every"] == 0 or done[phase] == total:
                save_whole(_to_cpu(
                    {"outfit": net.state_dict(), "pose": pose.state_dict(), "opt": opt.state_dict(),
                     "opt_phase": phase, "done": torch.tensor([done[p] for p in PHASES]),
                     "elapsed": torch.tensor(elapsed + time.time() - t0), "config": json.dumps(config),
                     "data": json.dumps(data), "device": str(dev)}),
                    ckpt_dir / f"step_{sum(done.values()):07d}.pt",
                )
        elapsed += time.time() - t0
        summary["phases"][phase] = {"steps": total, "last": stats}
        state = None
    summary["seconds"] = round(elapsed, 1)
    summary["device"] = ran_on or str(dev)  # where the last steps ran (a rerun with nothing to do: the checkpoint's)
    if dev.type == "cuda" and ran_on == str(dev):
        summary["device_name"] = torch.cuda.get_device_name(dev)
    return net.cpu(), pose.cpu(), summary
