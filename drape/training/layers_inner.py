"""`drape train mgn-inner`: MGN's inner-layer network (drape.models.layers.InnerPSD) of one served inner template,
trained without ground truth by physics losses (as PBNS / MGN's single-layer network).

The template is the inner layer of a served combination (drape.runtime.layers: `pair` generated as one layered
outfit of `vertices` vertices with `outfit_seed`, split; the inner part). Skin weights come from the body (the
inverse-distance blend of the `weights_k` nearest body vertices' weights) and stay fixed; the network learns the
pose-space offsets. Loss per batch of `batch_frames` poses (root rotation zeroed, so +Y is up):
    1e3 * (edge * mean |l - l0| + bend * normal Laplacian^2 + collision * mean relu(eps - d_body)
           + gravity * mean height + offset_l2 * mean |offset|^2)
(lengths in metres; d_body: DeePSD's posed-body signed distance, drape.training.physics.BodyCollider).

Training poses: `procedural_motions` seeded procedural motions, the embedded clips minus `heldout_clips`, and the
real CMU clips of `mocap.train`. Every `validate_every` steps the model is measured on the validation split
(`validation`: other procedural seeds and real clips no training or evaluation uses; `frames_per_clip` frames
each) as it is served: inside the posed body (exact closest triangle, %) + edge error (mm), the DeePSD rule;
the lowest score's weights are kept (`best.pt`) and exported. Checkpoints go to `checkpoints/mgn_inner_<inner>/`
(git-ignored); a rerun resumes from the latest. Seeded; the config is recorded in every checkpoint, and a rerun
of another config is refused. The config fixes the training poses and the validation motions but for one thing:
the embedded clips (drape.assets.motion.list_clips, minus `heldout_clips`) join the pose pool, so their names are
recorded too and a rerun after a clip was added or removed is refused as well.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from drape.assets.body import Body, load_body
from drape.assets.motion import list_clips
from drape.assets.outfits import split_outfit
from drape.geometry.mesh import neighbour_table, unique_edges
from drape.models.layers import InnerConfig, InnerPSD
from drape.training import physics
from drape.training.config_file import named_config, read_config
from drape.training.deepsd_data import pose_pool
from drape.training.deepsd_validation import Poser, measure_poser
from drape.training.validated_steps import restore_best, resume, save_step


def load_config(inner: str, path: str | Path | None = None) -> dict:
    return read_config(path, "mgn_inner") if path else named_config("mgn_inner", inner, "--inner")


def template(cfg: dict) -> tuple[np.ndarray, np.ndarray]:
    """The inner template: vertices (N, 3) float32 m in rest pose on the config's body, faces (F, 3) int32."""
    inner, _ = split_outfit(cfg["pair"], cfg["vertices"], seed=cfg["outfit_seed"], body=cfg["body"])
    return inner


def body_weights(vertices: np.ndarray, body: Body, k: int) -> np.ndarray:
    """Skin weights from the body: (N, 3) m -> (N, 24) float32, the inverse-distance blend of the k nearest body
    vertices' weights (k = 1: the nearest vertex's), rows summing to 1."""
    from scipy.spatial import cKDTree

    d, idx = cKDTree(body.vertices).query(np.asarray(vertices, np.float64), k=k)
    d, idx = d.reshape(len(vertices), -1), idx.reshape(len(vertices), -1)
    w = 1.0 / np.maximum(d, 1e-4)
    w /= w.sum(axis=1, keepdims=True)
    out = np.einsum("nk,nkj->nj", w, np.asarray(body.weights, np.float64)[idx])
    return (out / out.sum(axis=1, keepdims=True)).astype(np.float32)


class InnerTask:
    """The template's tensors, the body collider and the losses, built once."""

    def __init__(self, cfg: dict):
        self.cfg = cfg
        self.vertices, self.faces = template(cfg)
        self.body = load_body(cfg["body"])
        self.weights = body_weights(self.vertices, self.body, cfg["weights_k"])
        self.rest = torch.as_tensor(self.vertices)
        self.faces_t = torch.as_tensor(self.faces, dtype=torch.int64)
        idx, w = neighbour_table(self.faces, len(self.vertices))
        self.nbr_idx, self.nbr_w = torch.as_tensor(idx), torch.as_tensor(w)
        self.edges = torch.as_tensor(unique_edges(self.faces))
        self.rest_len = (self.rest[self.edges[:, 0]] - self.rest[self.edges[:, 1]]).norm(dim=-1)
        self.w = torch.as_tensor(self.weights)
        self.joints = torch.as_tensor(self.body.joints)
        self.collider = physics.BodyCollider(self.body, load_body(cfg["body"], proxy=True), self.vertices)

    def loss(self, model: InnerPSD, poses: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        """poses (B, 24, 3) rad, root zeroed -> (loss, stats)."""
        lw = self.cfg["loss"]
        offsets = model(poses.reshape(len(poses), -1))
        transforms = physics.skinning_transforms(poses, self.joints)
        v = physics.lbs(self.rest + offsets, self.w, transforms)
        l_edge = physics.edge_loss(v, self.edges, self.rest_len)
        l_bend = physics.bending_loss(v, self.faces_t, self.nbr_idx, self.nbr_w)
        sd = self.collider.signed_distance(v, transforms)
        l_coll = physics.collision_loss(sd, lw["eps"])
        l_grav = v[..., 1].mean()
        l_off = (offsets**2).sum(-1).mean()
        loss = 1e3 * (lw["edge"] * l_edge + lw["bend"] * l_bend + lw["collision"] * l_coll
                      + lw["gravity"] * l_grav + lw["offset_l2"] * l_off)
        return loss, {"edge_mm": float(l_edge.detach()) * 1e3, "inside": float((sd < 0).float().mean()),
                      "coll_mm": float(l_coll.detach()) * 1e3, "off_mm": float(l_off.detach().sqrt()) * 1e3}


def pose_inner(model: InnerPSD, task: InnerTask, poses: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """The network in numpy terms (what the runtime computes): poses (T, 24, 3), trans (T, 3) -> (T, N, 3) m."""
    from drape.runtime.deepsd import Rig, pose_outfit

    with torch.no_grad():
        keys = model.coefficients(torch.as_tensor(poses, dtype=torch.float32).reshape(len(poses), -1)).numpy()
    rig = Rig(weights=task.weights, blend_shapes=model.basis.detach().numpy())
    return pose_outfit(task.vertices, rig, keys, task.body.joints, poses, trans)


def measure(cfg: dict, vertices: np.ndarray, faces: np.ndarray, body: Body, pose: Poser) -> dict:
    """The validation split's figures of one poser (deepsd_validation.measure_poser on the config's body) and
    score = inside % + edge error mm."""
    figures = measure_poser(cfg, vertices, faces, cfg["body"], body, pose)
    return {"score": figures["inside_triangle_pct"] + figures["edge_error_mm"], **figures}


def pool_clips(cfg: dict) -> dict[str, list[str]]:
    """What of the training poses the config does not name: {"train_embedded_clips": the embedded clips the pose
    pool reads (deepsd_data.pose_pool: all but `heldout_clips`)}. The procedural motions, the real clips and the
    validation motions are the config's own."""
    return {"train_embedded_clips": [c for c in list_clips() if c not in cfg["heldout_clips"]]}


def train(cfg: dict, ckpt_dir: str | Path, log: Callable[[str], object] = print) -> tuple[InnerPSD, InnerTask, dict]:
    """Train (or resume) one inner template's network; returns the validation-chosen model, its task and a
    summary (steps, seconds, the validation record)."""
    from tqdm import tqdm

    ckpt_dir = Path(ckpt_dir)
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg["seed"])
    task = InnerTask(cfg)
    model = InnerPSD(InnerConfig(num_vertices=len(task.vertices), **cfg["model"]))
    opt = torch.optim.Adam(model.parameters(), lr=cfg["lr"])
    record: dict = {"rule": "lowest inside % + edge error mm, validation split", "steps": {}}
    sequences = pool_clips(cfg)
    done, elapsed, record = resume(ckpt_dir, model, opt, record, log, cfg, sequences)
    pool = torch.as_tensor(pose_pool(cfg))
    log(f"{cfg['inner']}: {len(task.vertices)} vertices, {len(pool)} training poses")
    total = int(cfg["steps"])
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=total, eta_min=cfg["lr"] * 0.05,
                                                       last_epoch=done - 1 if done else -1)
    bar = tqdm(range(done, total), initial=done, total=total, desc=cfg["inner"])
    t0 = time.time()
    for step in bar:
        rng = np.random.default_rng([cfg["seed"], step])
        poses = pool[torch.as_tensor(rng.integers(len(pool), size=cfg["batch_frames"]))]
        if cfg.get("pose_noise"):
            noise = torch.as_tensor(rng.normal(0, cfg["pose_noise"], poses.shape), dtype=torch.float32)
            noise[:, 0] = 0.0
            poses = poses + noise
        loss, stats = task.loss(model, poses)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        bar.set_postfix({k: round(v, 4) for k, v in stats.items()})
        done = step + 1
        if done % cfg["validate_every"] == 0 or done == total:
            model.eval()
            figures = measure(cfg, task.vertices, task.faces, task.body,
                              lambda p, t: pose_inner(model, task, p, t))
            model.train()
            record["steps"][str(done)] = figures
            log(f"step {done}: validation {figures['inside_triangle_pct']:.2f}% inside, "
                f"{figures['edge_error_mm']:.2f} mm edge error")
            save_step(ckpt_dir, model, opt, done, elapsed + time.time() - t0, record, cfg, sequences)
    elapsed += time.time() - t0
    best = restore_best(ckpt_dir, model, record)
    log(f"chosen on validation: step {best} ({record['steps'][best]['score']:.2f})")
    return model, task, {"steps": total, "seconds": round(elapsed, 1), "validation": record}


def deepsd_validation(cfg: dict, vertices: np.ndarray, faces: np.ndarray) -> dict:
    """DeePSD's served rig of the same template (the engine's rig, as /v1/layers/animate poses it) on the same
    validation split, for the choice of what poses the inner layer."""
    from drape.runtime.engine import Engine

    engine = Engine(refine_workers=1)
    try:
        rig = engine.rig(vertices, faces, cfg["body"])
        return measure(cfg, vertices, faces, load_body(cfg["body"]),
                       lambda p, t: np.concatenate(list(engine.pose_chunks(rig, p, t))))
    finally:
        engine.close()


def export_trained(model: InnerPSD, task: InnerTask, summary: dict, out: str | Path,
                   log: Callable[[str], object] = print) -> list[Path]:
    """Measure DeePSD on the validation split beside the chosen model, record which is served (the lower
    score) and export (drape.export.layers) to `out`."""
    from drape.export.layers import export_inner

    cfg = task.cfg
    ours = summary["validation"]["steps"][str(summary["validation"]["chosen"])]
    theirs = deepsd_validation(cfg, task.vertices, task.faces)
    served = "mgn_inner" if ours["score"] < theirs["score"] else "deepsd"
    log(f"validation score: mgn_inner {ours['score']:.2f}, deepsd {theirs['score']:.2f} -> serving {served}")
    return export_inner(model, out, vertices=task.vertices, faces=task.faces, weights=task.weights, manifest={
        "template": cfg["inner"], "pair": cfg["pair"], "body": cfg["body"], "served": served,
        "validation": ours, "deepsd_validation": theirs, "config": cfg,
        "training": {k: v for k, v in summary.items() if k != "validation"},
        "validation_steps": summary["validation"]["steps"]})
