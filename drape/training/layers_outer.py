"""`drape train mgn-outer`: MGN's outer-layer network (drape.models.layers.OuterTransformer) of one served
combination, trained on its two-layer simulations (`make layers-data`: data/layers/<inner>_<outer>/).

The inner layer the network reads is the one served: the shipped inner-layer network of the inner template
(drape/assets/models/mgn_inner/<inner>/, through ONNX Runtime as the runtime runs it; its sha256 is recorded, and
the runtime serves the outer network only beside that inner network). Its pose keys are the decoder's input,
its posed vertices the surface of the repulsion loss. The outer template's skin weights come from the body
(layers_inner.body_weights) and stay fixed; the network predicts the coefficients of a learned basis per frame.

Loss per batch of `batch_windows` windows of `window` frames, on `loss_frames` random frames of each (the network
reads every frame; the body term on `body_frames` of them; lengths in metres):
    1e3 * (vertex * mean |v - v_sim|^2 + laplacian * mean |L v - L v_sim|^2
           + repulsion * mean relu(eps - (v - p) . n_p)    (MGN Eq. 12: p the nearest served inner vertex among
                                                             the `candidates` nearest at rest, n_p its normal;
                                                             where p is within `cover` and not on a boundary)
           + body * mean relu(eps_body - d_body))           (the posed body's signed distance, as the inner's)
With `target_follows_inner` [full, zero] (m), the target of the vertex and Laplacian terms is the simulated outer
layer moved with the served inner layer (follow_inner: the simulation's inner layer is not the one served, and
the outer layer is judged against the served one); validation still measures against the simulation.
With `target_refined` true, each training target (after follow_inner) is then moved out of the body and the
served inner layer by the served post step between layers (OuterTask.refine_targets).
With `body_triangles` true, the body term measures to the closest point on the body's triangles around the 3
nearest posed body vertices (physics.BodyCollider's `triangles`), not to the nearest candidate's tangent plane.
Data: the dataset's "train" split (training H_in values x procedural motions; `train_items`, when the config
names them, those alone), with the sequences the quality gate rejected only for checks in `tolerated_checks`
(the simulated inner layer's body penetration: the network never reads the simulated inner layer; the outer
layer's own checks still apply); the "test" split (held-out H_in bins x the held-out procedural motion) is the
validation split: every `validate_every` steps the model is
run as served (windows at half stride, blended) and measured: outer RMSE against the simulation (mm), L-Coll
against the served inner layer and H-Coll (inside the body); the lowest RMSE's weights among the steps with
L-Coll <= `max_l_coll_pct` (and H-Coll <= `max_h_coll_pct` where the config sets one) are kept (`best.pt`) and exported. DeePSD's served rig of the outer template alone is measured on the same split by
the same rule; the lower score is served.
Real motion without simulation (`mocap`, where the config has it): the network is also trained on
`mocap.windows` windows per step of the real CMU clips `mocap.train` (imported at `mocap.fps`, cached as DeePSD's
training clips are) and of the embedded clips `mocap.embedded` (none of the evaluation's), H_in drawn uniformly
in the config's range, by the terms that need no simulation: repulsion, body and the relative edge-length error against the outer template at rest (weights `mocap.loss`); and it is
validated on the clips `mocap.validation` (real CMU or embedded clips, `mocap.validation_frames` frames each, no
training or evaluation uses them): their L-Coll and H-Coll are capped by `max_clip_l_coll_pct` / `max_clip_h_coll_pct` in the rule.
Checkpoints go to `checkpoints/mgn_outer_<outer>/` (git-ignored); a rerun resumes from the latest, and refuses
(ValueError) checkpoints of another config or of a run on other training or validation sequences (dataset keys).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from drape.assets.body import load_body
from drape.assets.motion import list_clips, load_clip
from drape.assets.outfits import split_outfit
from drape.geometry.character_space import motion_features
from drape.geometry.mesh import boundary_vertices, neighbour_table, unique_edges
from drape.geometry.mesh_io import load_mesh
from drape.geometry.metrics import sted
from drape.geometry.skeleton import PARENTS
from drape.models.layers import OuterConfig, OuterTransformer
from drape.runtime.deepsd import Rig, pose_outfit
from drape.runtime.layers import INNER_MODELS, InnerModel, blend_windows, window_starts
from drape.training import physics
from drape.training.config_file import named_config, read_config
from drape.training.deepsd_data import mocap_motion, repairs_flips
from drape.training.layers_inner import body_weights
from drape.training.validated_steps import restore_best, resume, save_step


def load_config(outer: str, path: str | Path | None = None) -> dict:
    return read_config(path, "mgn_outer") if path else named_config("mgn_outer", outer, "--outer")


@dataclass
class Sequence:
    """One simulated sequence, prepared: T frames; key, motion, thickness (m); features (T, 78); poses (T, 24, 3)
    rad; trans (T, 3) m; inner_keys (T, Ki) and inner (T, Ni, 3) m (the served inner network's); outer (T, No, 3)
    m (the simulation's; None for a real clip nobody simulated); rejected_for: the quality-gate checks it failed
    (tolerated ones; empty when accepted); target: the training target where it is not `outer` (follow_inner)."""

    key: str
    motion: str
    thickness: float
    features: np.ndarray
    poses: np.ndarray
    trans: np.ndarray
    inner_keys: np.ndarray
    inner: np.ndarray
    outer: np.ndarray | None
    rejected_for: list[str]
    target: np.ndarray | None = None  # (T, No, 3) m: what training compares with, where not `outer` (follow_inner, refined)


class OuterTask:
    """The combination's templates, the served inner network, the dataset and the losses, built once."""

    def __init__(self, cfg: dict, data_root: str | Path | None = None):
        self.cfg = cfg
        (self.inner_vertices, self.inner_faces), (self.vertices, self.faces) = split_outfit(
            cfg["pair"], cfg["vertices"], seed=cfg["outfit_seed"], body=cfg["body"])
        self.body = load_body(cfg["body"])
        self.inner_model = InnerModel(INNER_MODELS / cfg["inner"])
        if not np.allclose(self.inner_model.vertices, self.inner_vertices, atol=1e-6):
            raise ValueError(f"the shipped {cfg['inner']} inner network was trained on another template")
        self.weights = body_weights(self.vertices, self.body, cfg["weights_k"])
        self.data_dir = Path(data_root or cfg["data"])
        self._check_templates()
        # torch constants
        self.rest = torch.as_tensor(self.vertices)
        self.w = torch.as_tensor(self.weights)
        self.joints = torch.as_tensor(np.array(self.body.joints, np.float32))
        idx, w = neighbour_table(self.faces, len(self.vertices))
        self.nbr_idx, self.nbr_w = torch.as_tensor(idx), torch.as_tensor(w)
        self.inner_faces_t = torch.as_tensor(self.inner_faces, dtype=torch.int64)
        from scipy.spatial import cKDTree

        _, cand = cKDTree(self.inner_vertices).query(self.vertices, k=cfg["candidates"])
        self.candidates = torch.as_tensor(cand, dtype=torch.int64)  # (No, k)
        self.inner_boundary = torch.as_tensor(boundary_vertices(self.inner_faces, len(self.inner_vertices)))
        self.edges = torch.as_tensor(unique_edges(self.faces), dtype=torch.int64)  # (E, 2)
        self.collider = physics.BodyCollider(self.body, load_body(cfg["body"], proxy=True), self.vertices,
                                             triangles=bool(cfg.get("body_triangles", False)))

    def _check_templates(self) -> None:
        inner, outer = self.cfg["pair"].split(",")
        if not (self.data_dir / "manifest.json").is_file():
            raise FileNotFoundError(f"{self.data_dir}: no two-layer simulations here (no manifest.json); "
                                    "make layers-data simulates them (docs/layers.md)")
        for name, (v, f) in ((inner, (self.inner_vertices, self.inner_faces)), (outer, (self.vertices, self.faces))):
            dv, df = load_mesh(self.data_dir / f"{name}.obj")
            if dv.shape != v.shape or not np.allclose(dv, v, atol=1e-5) or not np.array_equal(df, f):
                raise ValueError(f"{self.data_dir / f'{name}.obj'} is not the served {name} template "
                                 f"(make layers-data makes it with LAYERS_SEED={self.cfg['outfit_seed']})")

    def sequences(self, split: str) -> list[Sequence]:
        """The dataset's sequences of one split ("train" | "test"), prepared."""
        manifest = json.loads((self.data_dir / "manifest.json").read_text())
        tolerated = set(self.cfg.get("tolerated_checks", []))
        usable = manifest["items"] + [r for r in manifest.get("rejected", []) if "file" in r and
                                      {reason.split(" ")[0] for reason in r["reasons"]} <= tolerated]
        out = []
        for item in usable:
            if item["split"] != split or not (self.data_dir / item["file"]).exists():
                continue
            h = float(manifest["params"][item["params"]]["inner_thickness"])
            low, high = self.cfg["thickness"]
            if not low <= h <= high:
                raise ValueError(f"{item['key']}: H_in {h} m outside the config's thickness [{low}, {high}]")
            with np.load(self.data_dir / item["file"], allow_pickle=False) as z:
                poses, trans = z["poses"].astype(np.float32), z["trans"].astype(np.float32)
                fps = float(z["fps"])
                outer = z["outer_vertices"].astype(np.float32)
                sim_inner = z["inner_vertices"].astype(np.float32)
            seq = self.prepared(item["key"], item["motion"], h, poses, trans, fps, outer,
                                [reason.split(" ")[0] for reason in item.get("reasons", [])])
            if self.cfg.get("target_follows_inner"):
                full, zero = self.cfg["target_follows_inner"]
                seq.target = follow_inner(outer, sim_inner, seq.inner, full, zero)
            out.append(seq)
        return out

    def refine_targets(self, seqs: list[Sequence], workers: int = 2) -> None:
        """Each sequence's training target (its `target`, else `outer`) moved out of the body and out of the
        served inner layer by the served post step between layers (refined_outer), in `workers` processes
        (about 0.3 s a frame each for the long sleeve). The simulated outer layer itself lies partly inside the
        body (3.0% of the long sleeve's vertex-frames over its 33 training sequences, 0.4% of the jacket's, as the
        simulation's quality gate counts them), so the vertex term pulls the network where the body term pushes
        it out."""
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        from tqdm import tqdm

        jobs = [(s.inner, self.inner_faces, s.outer if s.target is None else s.target, self.faces,
                 self.body.pose(s.poses, s.trans), self.body.faces, s.thickness) for s in seqs]
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            done = list(tqdm(pool.map(refined_outer, jobs), total=len(jobs), desc="refining targets"))
        for s, (m, _) in zip(seqs, done, strict=True):
            s.target = m
        n = sum(f["vertex_frames"] for _, f in done)
        tqdm.write("refined targets: outer in the body {:.2f}% -> {:.2f}%, within H_in of the inner {:.2f}% -> "
                   "{:.2f}% (the refiner's own queries); moved {:.2f} mm mean, {:.1f} mm at the 99th "
                   "percentile".format(*(100 * sum(f[k] for _, f in done) / n for k in (
                       "in_body_before", "in_body_after", "in_inner_before", "in_inner_after")),
                       sum(f["moved_mm_mean"] * f["vertex_frames"] for _, f in done) / n,
                       float(np.max([f["moved_mm_p99"] for _, f in done]))))

    def prepared(self, key: str, motion: str, thickness: float, poses: np.ndarray, trans: np.ndarray, fps: float,
                 outer: np.ndarray | None, rejected_for: list[str]) -> Sequence:
        """A Sequence of a motion: the features, the served inner network's keys and posed inner layer."""
        keys = self.inner_model.pose_keys(poses)
        inner = pose_outfit(self.inner_vertices, self.inner_model.rig, keys, self.body.joints, poses, trans)
        return Sequence(key, motion, thickness, motion_features(poses, trans, self.body.joints, PARENTS, fps), poses,
                        trans, keys, inner, outer, rejected_for)

    def clip_sequences(self, names: list[str], thickness: float, max_frames: int | None = None) -> list[Sequence]:
        """Clips as Sequences without simulation (outer None), the first `max_frames` frames, at `thickness` m:
        the config's real clips (`mocap`: dir, fps; imported on the body by deepsd_data.mocap_motion, cached) and
        embedded clips, named as drape.assets.motion.list_clips names them (load_clip, at their own fps)."""
        mocap = self.cfg["mocap"]
        repair = repairs_flips(mocap)
        embedded = set(list_clips())
        out = []
        for name in names:
            if name in embedded:
                clip = load_clip(name)
                poses, trans, fps = clip.poses.astype(np.float32), clip.trans.astype(np.float32), clip.fps
            else:
                fps = float(mocap["fps"])
                poses, trans = mocap_motion(mocap["dir"], name, fps, self.cfg["body"], flips=repair)
            poses, trans = poses[:max_frames], trans[:max_frames]
            out.append(self.prepared(f"clip:{name}", name, thickness, poses, trans, fps, None, []))
        return out

    def laplacian(self, v: torch.Tensor) -> torch.Tensor:
        return v - (v[:, self.nbr_idx] * self.nbr_w[None, ..., None]).sum(dim=2)

    def pose(self, offsets: torch.Tensor, poses: torch.Tensor, trans: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """offsets (B, No, 3), poses (B, 24, 3), trans (B, 3) -> (posed (B, No, 3) m, transforms (B, 24, 3, 4))."""
        transforms = physics.skinning_transforms(poses, self.joints)
        return physics.lbs(self.rest + offsets, self.w, transforms) + trans[:, None], transforms

    def repulsion_distance(self, v: torch.Tensor, inner: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """v (B, No, 3), inner (B, Ni, 3) -> ((v - p) . n_p (B, No) m, judged (B, No) bool): p the nearest of the
        vertex's candidate inner vertices, n_p its normal; judged where p is not on the inner's boundary (past a
        hem or an open front no side is defined) and within `cover` m (as L-Coll judges: drape.sim.quality)."""
        normals = physics.vertex_normals(inner, self.inner_faces_t)
        with torch.no_grad():
            d2, at = ((inner[:, self.candidates] - v.detach()[:, :, None]) ** 2).sum(-1).min(-1)  # (B, No)
            nearest = self.candidates[None].expand(len(v), -1, -1).gather(2, at[..., None])[..., 0]
            judged = ~self.inner_boundary[nearest] & (d2 < self.cfg["cover"] ** 2)
        b = torch.arange(len(v))[:, None]
        return ((v - inner[b, nearest]) * normals[b, nearest]).sum(-1), judged

    def posed_batch(self, model: OuterTransformer, batch: dict[str, torch.Tensor],
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The network on a batch's windows, posed on its picked frames -> (v (B*F, No, 3) m, trans (B*F, 3),
        transforms (B*F, 24, 3, 4))."""
        coefficients = model.coefficients(batch["features"], batch["thickness"], batch["inner_keys"])
        coefficients = coefficients.gather(1, batch["pick"][..., None].expand(-1, -1, coefficients.shape[-1]))
        offsets = torch.einsum("bk,knc->bnc", coefficients.flatten(0, 1), model.basis)
        trans = batch["trans"].flatten(0, 1)
        v, transforms = self.pose(offsets, batch["poses"].flatten(0, 1), trans)
        return v, trans, transforms

    def collision_terms(self, v: torch.Tensor, inner: torch.Tensor, trans: torch.Tensor, transforms: torch.Tensor,
                        lw: dict, thickness: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, dict[str, float]]:
        """MGN Eq. 12's repulsion from the inner layer and the body term on `lw["body_frames"]` of the frames:
        v (B, No, 3), inner (B, Ni, 3) m -> (repulsion, body, stats: shares behind the inner / inside the body).
        The repulsion's margin is `lw["eps"]` m, or with `lw["margin_thickness"]` each frame's H_in (thickness (B,)
        m; at least eps): the simulated outer keeps about H_in from the inner (its gap's 10th percentile is H_in +
        0.5 mm across the sampled range), where a fixed margin taught the network to ignore H_in."""
        sd_all, judged = self.repulsion_distance(v, inner)
        sd_inner = sd_all[judged]
        margin: torch.Tensor | float = lw["eps"]
        if lw.get("margin_thickness") and thickness is not None:
            margin = torch.clamp(thickness, min=lw["eps"])[:, None].expand_as(sd_all)[judged]
        l_rep = torch.relu(margin - sd_inner).sum() / max(len(sd_inner), 1)
        few = torch.linspace(0, len(v) - 1, min(lw["body_frames"], len(v))).long()  # spread over the windows
        sd_body = self.collider.signed_distance(v[few] - trans[few, None], transforms[few])
        l_body = physics.collision_loss(sd_body, lw["eps_body"])
        return l_rep, l_body, {"behind": float((sd_inner < 0).float().mean()),
                               "inside": float((sd_body < 0).float().mean())}

    def clip_loss(self, model: OuterTransformer, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, float]]:
        """The terms that need no simulation, on windows of real clips (`mocap.loss`: repulsion, body, edge; eps,
        eps_body, body_frames from `loss`): 1e3 * (repulsion + body + edge * mean relative edge-length error^2
        against the outer template at rest)."""
        lw = {**self.cfg["loss"], **self.cfg["mocap"]["loss"]}
        v, trans, transforms = self.posed_batch(model, batch)
        l_rep, l_body, stats = self.collision_terms(v, batch["inner"].flatten(0, 1), trans, transforms, lw,
                                                    frame_thickness(batch))
        l_edge = edge_length_loss(v, self.rest[None], self.edges)
        loss = 1e3 * (lw["repulsion"] * l_rep + lw["body"] * l_body + lw["edge"] * l_edge)
        return loss, {"clip_" + k: v for k, v in stats.items()} | {"clip_edge": float(l_edge.detach().sqrt())}

    def loss(self, model: OuterTransformer, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, float]]:
        lw = self.cfg["loss"]
        v, trans, transforms = self.posed_batch(model, batch)
        gt = batch["outer"].flatten(0, 1)
        l_vert = ((v - gt) ** 2).sum(-1).mean()
        l_lap = ((self.laplacian(v) - self.laplacian(gt)) ** 2).sum(-1).mean()
        l_rep, l_body, collisions = self.collision_terms(v, batch["inner"].flatten(0, 1), trans, transforms, lw,
                                                         frame_thickness(batch))
        loss = 1e3 * (lw["vertex"] * l_vert + lw["laplacian"] * l_lap + lw["repulsion"] * l_rep + lw["body"] * l_body)
        stats = {"rmse_mm": float(l_vert.detach().sqrt()) * 1e3, **collisions}
        if lw.get("edge", 0.0) > 0:  # against a crumpled layer
            l_edge = edge_length_loss(v, gt, self.edges)
            loss = loss + 1e3 * lw["edge"] * l_edge
            stats["edge"] = float(l_edge.detach().sqrt())
        if lw.get("temporal", 0.0) > 0:  # sample_batch(pairs=True) gives the frames in pairs (t, t + 1)
            l_step = step_loss(v, gt)
            loss = loss + 1e3 * lw["temporal"] * l_step
            stats["step_mm"] = float(l_step.detach().sqrt()) * 1e3
        return loss, stats


def refined_outer(job: tuple) -> tuple[np.ndarray, dict]:
    """(inner (T, Ni, 3), inner_faces, outer (T, No, 3), outer_faces, body (T, M, 3), body_faces, H_in) m ->
    (the outer layer after drape.geometry.layers.refine_layers (the refined inner dropped): (T, No, 3) float32 m,
    figures: vertex_frames; outer vertex-frames in the body and within H_in of the inner, before and after, as
    the refiner counts them; the moves' mean and 99th percentile, mm)."""
    from drape.geometry.layers import refine_layers

    _, moved, report = refine_layers(*job)
    move = np.linalg.norm(moved - job[2], axis=-1) * 1e3
    return moved, {"vertex_frames": int(move.size), "in_body_before": sum(report.outer_in_body_before),
                   "in_body_after": sum(report.outer_in_body_after),
                   "in_inner_before": sum(report.outer_in_inner_before),
                   "in_inner_after": sum(report.outer_in_inner_after),
                   "moved_mm_mean": float(move.mean()), "moved_mm_p99": float(np.percentile(move, 99))}


def follow_inner(outer: np.ndarray, sim_inner: np.ndarray, served_inner: np.ndarray, full: float, zero: float,
                 ) -> np.ndarray:
    """The simulated outer layer moved with the inner layer the network reads: each outer vertex plus w times the
    served-minus-simulated displacement of its nearest simulated inner vertex, w = 1 within `full` m of it, 0
    beyond `zero` m, linear between (what lies on the t-shirt moves with it; what hangs free does not).
    outer (T, No, 3), sim_inner and served_inner (T, Ni, 3) m -> (T, No, 3) float32 m."""
    from scipy.spatial import cKDTree

    moved = np.array(outer, np.float32, copy=True)
    for t in range(len(outer)):
        d, j = cKDTree(sim_inner[t]).query(outer[t])
        w = np.clip((zero - d) / (zero - full), 0.0, 1.0)
        moved[t] += (w[:, None] * (served_inner[t, j] - sim_inner[t, j])).astype(np.float32)
    return moved


def edge_length_loss(v: torch.Tensor, truth: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """Mean squared relative edge-length error (STED's spatial part, squared): v (B, N, 3), truth (B or 1, N, 3)
    m, edges (E, 2) -> scalar, unitless."""
    lt = physics.edge_lengths(truth, edges)
    return (((physics.edge_lengths(v, edges) - lt) / lt.clamp_min(1e-6)) ** 2).mean()


def step_loss(v: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Mean squared error of the per-frame vertex steps: v, truth (2P, N, 3) m holding P pairs of consecutive
    frames (t, t + 1) in that order -> scalar, m^2 (per frame)."""
    return ((v.unflatten(0, (-1, 2)).diff(dim=1) - truth.unflatten(0, (-1, 2)).diff(dim=1)) ** 2).sum(-1).mean()


def frame_thickness(batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Each picked frame's H_in: thickness (B, 1) m over pick (B, F) -> (B * F,), in posed_batch's order."""
    return batch["thickness"].expand(-1, batch["pick"].shape[1]).flatten()


def sample_batch(seqs: list[Sequence], window: int, count: int, frames: int, rng: np.random.Generator,
                 pairs: bool = False, thickness: tuple[float, float] | None = None) -> dict[str, torch.Tensor]:
    """`count` random windows of `window` frames (sequences drawn in proportion to their windows): the network's
    inputs of every frame (features, inner_keys (B, W, .), thickness (B, 1)) and, for `frames` random frames of
    each window (`pick` (B, F)), what the loss compares (poses, trans, outer, inner (B, F, ...)). With `pairs`,
    the frames are frames // 2 random pairs of consecutive frames (t, t + 1), in that order (a temporal loss).
    With `thickness` (low, high) m, each window's H_in is drawn uniformly there instead of its sequence's. "outer"
    (a sequence's `target` where it has one) only where every sequence has a simulation."""
    sizes = np.array([len(s.poses) - window + 1 for s in seqs])
    picks = rng.choice(len(seqs), size=count, p=sizes / sizes.sum())
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("features", "inner_keys", "pick", "poses", "trans", "outer",
                                                          "inner", "thickness")}
    for i in picks:
        s = seqs[i]
        t0 = int(rng.integers(sizes[i]))
        if pairs:
            first = np.sort(rng.choice(window - 1, size=min(frames // 2, window - 1), replace=False))
            pick = np.stack([first, first + 1], 1).ravel()
        else:
            pick = np.sort(rng.choice(window, size=min(frames, window), replace=False))
        parts["features"].append(s.features[t0:t0 + window])
        parts["inner_keys"].append(s.inner_keys[t0:t0 + window])
        parts["pick"].append(pick)
        for k in ("poses", "trans", "inner"):
            parts[k].append(getattr(s, k)[t0 + pick])
        if s.outer is not None:
            parts["outer"].append((s.outer if s.target is None else s.target)[t0 + pick])
        h = s.thickness if thickness is None else rng.uniform(*thickness)
        parts["thickness"].append(np.array([h], np.float32))
    return {k: torch.as_tensor(np.stack(v)) for k, v in parts.items() if len(v) == count}


def predict_keys(model: OuterTransformer, seq: Sequence, window: int) -> np.ndarray:
    """The served prediction in torch: windows at half stride, blended (drape.runtime.layers) -> (T, K)."""
    starts, length = window_starts(len(seq.poses), window)
    with torch.no_grad():
        keys = model.coefficients(
            torch.as_tensor(np.stack([seq.features[s:s + length] for s in starts])),
            torch.full((len(starts), 1), seq.thickness),
            torch.as_tensor(np.stack([seq.inner_keys[s:s + length] for s in starts]))).numpy()
    return blend_windows(keys, starts, len(seq.poses))


PENALTY = 1000.0  # mm added to the score of a step whose L-Coll (or H-Coll) is over the config's cap


def collision_shares(task: OuterTask, seq: Sequence, v: np.ndarray) -> tuple[float, float]:
    """Of an outer layer v (T, No, 3) m posed along seq: (L-Coll, share behind the served inner layer;
    H-Coll, share inside the body, exact closest triangle), fractions."""
    from drape.training.layers_eval import h_coll, l_coll

    return (l_coll(v, seq.inner, task.inner_faces)[0],
            h_coll(v, task.body.pose(seq.poses, seq.trans), task.body.faces))


def measure_clips(task: OuterTask, seqs: list[Sequence], pose: Callable[[Sequence], np.ndarray]) -> dict:
    """L-Coll and H-Coll (%, as measure_sequences) of a poser over real clips nobody simulated."""
    per = {}
    for s in seqs:
        behind, inside = collision_shares(task, s, pose(s))
        per[s.key] = {"l_coll_pct": round(100 * behind, 3), "h_coll_pct": round(100 * inside, 3)}
    return {"clip_l_coll_pct": round(float(np.mean([p["l_coll_pct"] for p in per.values()])), 3),
            "clip_h_coll_pct": round(float(np.mean([p["h_coll_pct"] for p in per.values()])), 3),
            "clip_sequences": per}


def measure_all(task: OuterTask, seqs: list[Sequence], clips: list[Sequence], pose: Callable[[Sequence], np.ndarray],
                ) -> dict:
    """measure_sequences on the simulated validation sequences with the config's caps, and where there are real
    validation clips, measure_clips on them: PENALTY added once where their L-Coll or H-Coll is over
    max_clip_l_coll_pct / max_clip_h_coll_pct."""
    caps = collision_caps(task.cfg)
    figures = measure_sequences(task, seqs, pose, **caps)
    if clips:
        figures |= measure_clips(task, clips, pose)
        over = (figures["clip_l_coll_pct"] > float(task.cfg.get("max_clip_l_coll_pct", 100.0))
                or figures["clip_h_coll_pct"] > float(task.cfg.get("max_clip_h_coll_pct", 100.0)))
        if over and figures["score"] < PENALTY:
            figures["score"] = round(figures["score"] + PENALTY, 3)
    return figures


def measure_sequences(task: OuterTask, seqs: list[Sequence], pose: Callable[[Sequence], np.ndarray],
                      max_l_coll_pct: float = 100.0, max_h_coll_pct: float = 100.0) -> dict:
    """Outer RMSE against the simulation (mm), L-Coll (% outer vertices behind the served inner layer) and H-Coll
    (% outer vertices inside the body, exact closest triangle) of a poser over sequences; score = RMSE, plus
    PENALTY where L-Coll is over max_l_coll_pct or H-Coll over max_h_coll_pct."""
    sq, behind, inside, edges, per = [], [], [], [], {}
    for s in seqs:
        if s.outer is None:
            raise ValueError(f"{s.key} has no simulation to measure against (measure_clips measures real clips)")
        v = pose(s)
        e = ((v - s.outer) ** 2).sum(-1)
        sq.append(e)
        share, body_share = collision_shares(task, s, v)
        behind.append(share)
        inside.append(body_share)
        edges.append(sted(v, s.outer, task.faces)["sted"])
        per[s.key] = {"rmse_mm": round(float(np.sqrt(e.mean())) * 1e3, 2), "l_coll_pct": round(100 * share, 3),
                      "h_coll_pct": round(100 * inside[-1], 3), "sted": round(edges[-1], 4)}
    rmse = float(np.sqrt(np.mean(np.concatenate([e.ravel() for e in sq])))) * 1e3
    l_coll_pct, h_coll_pct = 100 * float(np.mean(behind)), 100 * float(np.mean(inside))
    over = l_coll_pct > max_l_coll_pct or h_coll_pct > max_h_coll_pct
    return {"score": round(rmse + (PENALTY if over else 0.0), 3), "rmse_mm": round(rmse, 3),
            "l_coll_pct": round(l_coll_pct, 3), "h_coll_pct": round(h_coll_pct, 3),
            "sted": round(float(np.mean(edges)), 4), "sequences": per}


def collision_caps(cfg: dict) -> dict[str, float]:
    """The validation rule's caps of a config: max_l_coll_pct, and max_h_coll_pct where it sets one."""
    return {"max_l_coll_pct": float(cfg["max_l_coll_pct"]), "max_h_coll_pct": float(cfg.get("max_h_coll_pct", 100.0))}


def pose_outer(model: OuterTransformer, task: OuterTask, seq: Sequence) -> np.ndarray:
    """The network as served (numpy posing of the blended keys) -> (T, No, 3) m."""
    keys = predict_keys(model, seq, model.cfg.window)
    rig = Rig(weights=task.weights, blend_shapes=model.basis.detach().numpy())
    return pose_outfit(task.vertices, rig, keys, task.body.joints, seq.poses, seq.trans)


def validation_clips(task: OuterTask) -> list[Sequence]:
    """The config's validation clips (`mocap.validation`, their first `mocap.validation_frames` frames, at the middle
    of the thickness range); none without `mocap`."""
    mocap = task.cfg.get("mocap")
    if not mocap:
        return []
    low, high = task.cfg["thickness"]
    return task.clip_sequences(mocap["validation"], (low + high) / 2, mocap["validation_frames"])


def train(cfg: dict, ckpt_dir: str | Path, log: Callable[[str], object] = print, data_root: str | Path | None = None,
          ) -> tuple[OuterTransformer, OuterTask, dict]:
    """Train (or resume) one combination's outer network; returns the validation-chosen model, its task and a
    summary (steps, seconds, sequences, the validation record)."""
    from tqdm import tqdm

    ckpt_dir = Path(ckpt_dir)
    torch.manual_seed(cfg["seed"])
    task = OuterTask(cfg, data_root)
    ckpt_dir.mkdir(parents=True, exist_ok=True)  # once there is something to train on
    train_seqs, val_seqs = task.sequences("train"), task.sequences("test")
    if cfg.get("train_items"):  # the config names the training sequences: all of them must be there
        missing = sorted(set(cfg["train_items"]) - {s.key for s in train_seqs})
        if missing:
            raise SystemExit(f"{task.data_dir}: missing training sequences {missing}; make layers-data simulates them")
        train_seqs = [s for s in train_seqs if s.key in set(cfg["train_items"])]
    if cfg.get("target_refined"):
        task.refine_targets(train_seqs)
    if not train_seqs or not val_seqs:
        raise SystemExit(f"{task.data_dir}: {len(train_seqs)} training and {len(val_seqs)} validation sequences; "
                         "make layers-data simulates them")
    mocap = cfg.get("mocap")
    low, high = cfg["thickness"]
    clip_train = (task.clip_sequences(mocap["train"] + mocap.get("embedded", []), (low + high) / 2,
                                      mocap.get("max_frames")) if mocap else [])
    clip_val = validation_clips(task)
    model = OuterTransformer(OuterConfig(num_vertices=len(task.vertices),
                                         num_inner_keys=task.inner_model.rig.blend_shapes.shape[0], **cfg["model"]))
    model.set_normalization(torch.as_tensor(np.concatenate([s.features for s in train_seqs + clip_train])),
                            torch.as_tensor(np.concatenate([s.inner_keys for s in train_seqs + clip_train])))
    opt = torch.optim.AdamW(model.parameters(), lr=cfg["lr"], weight_decay=cfg.get("weight_decay", 0.0))
    caps = collision_caps(cfg)
    record: dict = {"rule": f"lowest outer RMSE (mm) against the simulation among the steps with L-Coll <= "
                            f"{caps['max_l_coll_pct']}%" + (f" and H-Coll <= {caps['max_h_coll_pct']}%"
                                                             if "max_h_coll_pct" in cfg else "") + ", validation split"
                            + (f"; on the real validation clips L-Coll <= {cfg.get('max_clip_l_coll_pct', 100.0)}% "
                               f"and H-Coll <= {cfg.get('max_clip_h_coll_pct', 100.0)}%" if clip_val else ""),
                    "steps": {}}
    # the sequences, named by their dataset keys: a rerun after make layers-data added or dropped some is refused
    sequences = {"train": sorted(s.key for s in train_seqs), "validation": sorted(s.key for s in val_seqs)}
    done, elapsed, record = resume(ckpt_dir, model, opt, record, log, cfg, sequences)
    frames = sum(len(s.poses) for s in train_seqs)
    log(f"{cfg['pair']}: {len(task.vertices)} outer vertices; {len(train_seqs)} training sequences ({frames} frames), "
        f"{len(val_seqs)} validation sequences; {len(clip_train)} real training clips "
        f"({sum(len(s.poses) for s in clip_train)} frames), {len(clip_val)} real validation clips")
    total, warmup = int(cfg["steps"]), int(cfg.get("warmup", 0))

    def lr_at(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        return 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * (step - warmup) / max(total - warmup, 1)))

    bar = tqdm(range(done, total), initial=done, total=total, desc=cfg["pair"])
    t0 = time.time()
    model.train()
    for step in bar:
        for g in opt.param_groups:
            g["lr"] = cfg["lr"] * lr_at(step)
        batch = sample_batch(train_seqs, model.cfg.window, cfg["batch_windows"], cfg["loss_frames"],
                             np.random.default_rng([cfg["seed"], step]), pairs=cfg["loss"].get("temporal", 0.0) > 0)
        loss, stats = task.loss(model, batch)
        if mocap and clip_train:
            clip_batch = sample_batch(clip_train, model.cfg.window, mocap["windows"], mocap["loss_frames"],
                                      np.random.default_rng([cfg["seed"], step, 1]), thickness=(low, high))
            clip_loss, clip_stats = task.clip_loss(model, clip_batch)
            loss, stats = loss + clip_loss, stats | clip_stats
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        bar.set_postfix({k: round(v, 4) for k, v in stats.items()})
        done = step + 1
        if done % cfg["validate_every"] == 0 or done == total:
            model.eval()
            figures = measure_all(task, val_seqs, clip_val, lambda s: pose_outer(model, task, s))
            model.train()
            record["steps"][str(done)] = figures
            log(f"step {done}: validation RMSE {figures['rmse_mm']:.2f} mm, L-Coll {figures['l_coll_pct']:.2f}%, "
                f"H-Coll {figures['h_coll_pct']:.2f}%, STED {figures['sted']:.3f}"
                + (f"; real clips L-Coll {figures['clip_l_coll_pct']:.2f}%, H-Coll {figures['clip_h_coll_pct']:.2f}%"
                   if clip_val else ""))
            save_step(ckpt_dir, model, opt, done, elapsed + time.time() - t0, record, cfg, sequences)
    elapsed += time.time() - t0
    best = restore_best(ckpt_dir, model, record)
    log(f"chosen on validation: step {best} ({record['steps'][best]['score']:.2f} mm)")
    data = {**sequences, "train_frames": frames,
            "gate_rejected": {s.key: s.rejected_for for s in train_seqs + val_seqs if s.rejected_for}}
    if clip_train:
        data |= {"clips": [s.motion for s in clip_train], "clip_frames": sum(len(s.poses) for s in clip_train),
                 "clip_validation": [s.motion for s in clip_val]}
    return model, task, {"steps": total, "seconds": round(elapsed, 1), "data": data, "validation": record,
                         "val_seqs": val_seqs, "clip_val_seqs": clip_val}


def deepsd_validation(task: OuterTask, seqs: list[Sequence], clips: list[Sequence] | None = None) -> dict:
    """DeePSD's served rig of the outer template alone (as /v1/layers/animate poses it today) on the same
    validation sequences (and real validation clips)."""
    from drape.runtime.engine import Engine

    engine = Engine(refine_workers=1)
    try:
        rig = engine.rig(task.vertices, task.faces, task.cfg["body"])
        return measure_all(task, seqs, clips or [],
                           lambda s: np.concatenate(list(engine.pose_chunks(rig, s.poses, s.trans))))
    finally:
        engine.close()


def export_trained(model: OuterTransformer, task: OuterTask, summary: dict, out: str | Path,
                   log: Callable[[str], object] = print) -> list[Path]:
    """Measure DeePSD on the validation split beside the chosen model, record which is served (the lower RMSE)
    and export (drape.export.layers.export_outer) to `out`."""
    from drape.export.layers import export_outer

    cfg = task.cfg
    ours = summary["validation"]["steps"][str(summary["validation"]["chosen"])]
    theirs = deepsd_validation(task, summary["val_seqs"], summary.get("clip_val_seqs"))
    served = "mgn_outer" if ours["score"] < theirs["score"] else "deepsd"
    log(f"validation: mgn_outer {ours['rmse_mm']:.2f} mm RMSE, L-Coll {ours['l_coll_pct']:.2f}%; deepsd "
        f"{theirs['rmse_mm']:.2f} mm, {theirs['l_coll_pct']:.2f}% -> serving {served}")
    inner_manifest = task.inner_model.manifest
    return export_outer(model, out, vertices=task.vertices, faces=task.faces, weights=task.weights, manifest={
        "template": cfg["outer"], "inner": cfg["inner"], "pair": cfg["pair"], "body": cfg["body"], "served": served,
        "inner_network": {"version": inner_manifest["version"], "pose_sha256": inner_manifest["files"]["pose"]["sha256"]},
        "validation": ours, "deepsd_validation": theirs, "config": cfg,
        "training": {k: v for k, v in summary.items() if k not in ("validation", "val_seqs", "clip_val_seqs")},
        "validation_steps": {k: {m: v[m] for m in ("score", "rmse_mm", "l_coll_pct", "h_coll_pct", "sted",
                                                   "clip_l_coll_pct", "clip_h_coll_pct") if m in v}
                             for k, v in summary["validation"]["steps"].items()}})
