"""`drape eval layers`: the served layer combinations against two-layer simulations, on held-out motions.

Ground truth: drape.sim.layers.simulate_layers (MuJoCo; the outer colliding with the inner and the body) of each
served combination (drape.runtime.layers) at H_in = THICKNESS (held out of the outer networks' training) along the
DeepMimic clip dance_b (held out of DeePSD's, the inner and the outer networks' training) and the real CMU clip
02_01_walk (30 fps; used by no training; skipped without ../shared/data/mocap), FRAMES frames each. Simulations are cached under data/layers_eval/
(git-ignored; a missing one is simulated, about 2-3 minutes each on one core).

Rows, each against the simulation's frames of the same motion:
- `deepsd one outfit`: DeePSD rigs both layers as one outfit (how drape rigged a layered outfit before);
- `deepsd each alone`: DeePSD rigs each layer alone (its served 4-influence rig);
- `mgn inner`: the inner posed by the template's inner-layer network (where one ships), the outer as above;
- `served`: what POST /v1/layers/animate answers without refine (Engine.layer_chunks): the inner and outer
  networks where they serve (drape's layered model), else DeePSD's rig of the layer;
- `served + refine`: with refine (the post step against the body and between layers, thickness THICKNESS).
Columns: RMSE and Hausdorff (mm) of the inner and the outer against the simulation, the outer's STED; H-Coll of
each layer (share of vertices inside the body, exact closest triangle); L-Coll (outer vertices behind the inner
within 2 cm where it covers them: drape.sim.quality.outer_inner_distance). Speed: 300 frames of both layers
posed by the served models, and by DeePSD alone, in the same run (seconds, this machine).
Runs on numpy + ONNX Runtime (MuJoCo only to simulate a missing sequence).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from drape.assets.body import Body, load_body
from drape.assets.motion import Motion, import_motion, load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.metrics import hausdorff_mm, rmse_mm, sted
from drape.geometry.queries import signed_distance_to_mesh
from drape.runtime.deepsd import pose_outfit
from drape.runtime.engine import Engine, RefineSettings
from drape.runtime.layers import SEED, VERTICES, LayerCombination, load_inner_model
from drape.sim.quality import INSIDE_BAND, outer_inner_distance

# metres: the inner thickness simulated, posed and refined with: held out of the outer networks' training (in a
# held-out H_in bin of `make layers-data`; the nearest training values are 5.71 and 7.66 mm)
THICKNESS = 0.0067
FRAMES = 60
CACHE = Path("data") / "layers_eval"
REAL = Path("..") / "shared" / "data" / "mocap" / "02_01_walk.bvh"
CLIP = "dance_b"  # the embedded held-out clip
SPEED_FRAMES = 300


def h_coll(frames: np.ndarray, bodies: np.ndarray, faces: np.ndarray) -> float:
    """Share of vertices inside the body (exact closest triangle), frames (T, N, 3), bodies (T, M, 3)."""
    return float(np.mean([np.mean(signed_distance_to_mesh(x, b, faces) < 0)
                          for x, b in zip(frames, bodies, strict=True)]))


def l_coll(outer: np.ndarray, inner: np.ndarray, inner_faces: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Share of outer vertices behind the inner within INSIDE_BAND where it covers them -> (share, signed
    distances (T, No), covered (T, No))."""
    sd, covered = outer_inner_distance(outer, inner, inner_faces)
    return float(np.mean(covered & (sd < 0) & (sd >= -INSIDE_BAND))), sd, covered


def heldout_motions(body: Body, real: Path = REAL) -> list[Motion]:
    """dance_b and, where present, the real CMU clip 02_01_walk at 30 fps."""
    out = [load_clip(CLIP)]
    if real.exists():
        out.append(import_motion(real.read_bytes(), body, fps=30.0, name=real.stem).motion)
    return out


def simulated(c: LayerCombination, motion: Motion, frames: int, body: Body, cache: Path = CACHE) -> dict:
    """The two-layer simulation of a combination along a motion at THICKNESS (cached): inner (T, Ni, 3), outer
    (T, No, 3), poses (T, 24, 3), trans (T, 3)."""
    from drape.sim.layers import simulate_layers
    from drape.sim.params import LayerParams

    path = cache / f"{c.inner.name}+{c.outer.name}_{motion.name}_{frames}_{1000 * THICKNESS:g}mm.npz"
    if not path.exists():
        r = simulate_layers(c.inner.vertices, c.inner.faces, c.outer.vertices, c.outer.faces, body, motion,
                            LayerParams(inner_thickness=THICKNESS), frames=frames)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, inner=r.inner_vertices, outer=r.outer_vertices, poses=r.poses, trans=r.trans,
                 seconds_per_frame=r.seconds_per_frame)
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


Posed = tuple[np.ndarray, np.ndarray]  # inner (T, Ni, 3), outer (T, No, 3) float64 m


class Rows:
    """One combination's posers, made once: DeePSD's rigs (whole outfit, each layer), the inner network."""

    def __init__(self, engine: Engine, c: LayerCombination):
        self.engine, self.c = engine, c
        self.whole = generate_outfit([c.inner.name, c.outer.name], vertices=VERTICES, seed=SEED, body=c.inner.body)
        self.rigs = [engine.rig(v, f, c.inner.body) for v, f in
                     ((self.whole.vertices, self.whole.faces), (c.inner.vertices, c.inner.faces),
                      (c.outer.vertices, c.outer.faces))]
        self.network = load_inner_model(c.inner.name)
        self.joints = load_body(c.inner.body).joints

    def _pose(self, rig_index: int, poses: np.ndarray, trans: np.ndarray) -> np.ndarray:
        return np.concatenate(list(self.engine.pose_chunks(self.rigs[rig_index], poses, trans))).astype(np.float64)

    def mgn_inner(self, poses: np.ndarray, trans: np.ndarray) -> np.ndarray | None:
        n = self.network
        return None if n is None else pose_outfit(self.c.inner.vertices, n.rig, n.pose_keys(poses), self.joints,
                                                  poses, trans).astype(np.float64)

    def served(self, poses: np.ndarray, trans: np.ndarray, fps: float, refine: RefineSettings | None = None) -> Posed:
        parts = list(self.engine.layer_chunks(self.c, THICKNESS, poses, trans, refine=refine, fps=fps))
        return (np.concatenate([p[0] for p in parts]).astype(np.float64),
                np.concatenate([p[1] for p in parts]).astype(np.float64))

    def deepsd(self, poses: np.ndarray, trans: np.ndarray) -> tuple[Posed, Posed]:
        """DeePSD's layers: (rigged as one outfit, each rigged alone), each (inner, outer)."""
        whole = self._pose(0, poses, trans)
        layer = self.whole.garment
        return (whole[:, layer == 0], whole[:, layer == 1]), (self._pose(1, poses, trans), self._pose(2, poses, trans))

    def rows(self, poses: np.ndarray, trans: np.ndarray, fps: float) -> dict[str, Posed]:
        one, alone = self.deepsd(poses, trans)
        outer = alone[1]
        out = {"deepsd one outfit": one, "deepsd each alone": alone}
        mgn = self.mgn_inner(poses, trans)
        if mgn is not None:
            out["mgn inner"] = (mgn, outer)
        out["served"] = self.served(poses, trans, fps)
        out["served + refine"] = self.served(poses, trans, fps, RefineSettings())
        return out

    def speed(self, seconds: Callable[[Callable[[], object]], float]) -> dict[str, float]:
        """Seconds to pose SPEED_FRAMES frames of both layers: served (no refine) and DeePSD each alone."""
        clip = load_clip(CLIP)
        reps = -(-SPEED_FRAMES // clip.num_frames)
        poses = np.tile(clip.poses, (reps, 1, 1))[:SPEED_FRAMES]
        trans = np.tile(clip.trans, (reps, 1))[:SPEED_FRAMES]
        return {"served_s": seconds(lambda: self.served(poses, trans, clip.fps)),
                "deepsd_each_alone_s": seconds(lambda: (self._pose(1, poses, trans), self._pose(2, poses, trans)))}


def _best_of(fn: Callable[[], object], repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def evaluate(frames: int = FRAMES, log: Callable[[str], object] = print) -> dict:
    """Every served combination x held-out motion x row: the figures above. Returns {"combinations": {...}}."""
    engine = Engine(refine_workers=1)
    try:
        results: dict = {"thickness_m": THICKNESS, "frames": frames, "combinations": {}}
        for c in engine.layers.combinations():
            key = f"{c.inner.name}+{c.outer.name}"
            body = load_body(c.inner.body)
            rows = Rows(engine, c)
            entry: dict = {"inner_model": c.inner.model, "outer_model": c.outer.model, "motions": {}}
            for motion in heldout_motions(body):
                sim = simulated(c, motion, frames, body)
                poses, trans = sim["poses"].astype(np.float64), sim["trans"].astype(np.float64)
                bodies = body.pose(poses, trans).astype(np.float64)
                figures = {"simulation": _figures(sim["inner"], sim["outer"], None, bodies, c, body)}
                for label, posed in rows.rows(poses, trans, motion.fps).items():
                    figures[label] = _figures(*posed, sim, bodies, c, body)
                entry["motions"][motion.name] = figures
                log(f"{key} {motion.name}: " + ", ".join(f"{k} outer RMSE {v.get('outer_rmse_mm', 0):.1f} mm, "
                                                          f"H-Coll inner {v['h_coll_inner']:.2%}"
                                                          for k, v in figures.items()))
            entry["speed_300_frames"] = rows.speed(_best_of)
            results["combinations"][key] = entry
        return results
    finally:
        engine.close()


def _figures(inner: np.ndarray, outer: np.ndarray, sim: dict | None, bodies: np.ndarray, c: LayerCombination,
             body: Body) -> dict:
    out = {"h_coll_inner": h_coll(inner, bodies, body.faces), "h_coll_outer": h_coll(outer, bodies, body.faces),
           "l_coll": l_coll(outer, inner, c.inner.faces)[0]}
    if sim is not None:
        out.update({"inner_rmse_mm": rmse_mm(inner, sim["inner"]), "inner_hausdorff_mm": hausdorff_mm(inner, sim["inner"]),
                    "outer_rmse_mm": rmse_mm(outer, sim["outer"]), "outer_hausdorff_mm": hausdorff_mm(outer, sim["outer"]),
                    "outer_sted": sted(outer, sim["outer"], c.outer.faces)["sted"]})
    return out


def format_table(results: dict) -> str:
    """Markdown tables of `evaluate`'s figures, one per combination."""
    lines = []
    for key, entry in results["combinations"].items():
        lines += [f"### {key} (inner: {entry['inner_model']}, outer: {entry['outer_model']})", "",
                  "| motion | rows | inner RMSE mm | inner Haus mm | outer RMSE mm | outer Haus mm | outer STED "
                  "| H-Coll inner | H-Coll outer | L-Coll |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for motion, figures in entry["motions"].items():
            for label, f in figures.items():
                err = (" | ".join(f"{f[k]:.1f}" for k in ("inner_rmse_mm", "inner_hausdorff_mm", "outer_rmse_mm",
                                                         "outer_hausdorff_mm")) + f" | {f['outer_sted']:.3f}"
                       if "inner_rmse_mm" in f else " | | | | ")
                lines.append(f"| {motion} | {label} | {err} | {f['h_coll_inner']:.2%} | {f['h_coll_outer']:.2%} "
                             f"| {f['l_coll']:.2%} |")
        s = entry["speed_300_frames"]
        lines += ["", f"300 frames of both layers, posed: served {s['served_s']:.3f} s, DeePSD each alone "
                      f"{s['deepsd_each_alone_s']:.3f} s (best of 3, same run).", ""]
    return "\n".join(lines)


def write_results(results: dict, models: Path | None = None) -> list[Path]:
    """Put each combination's figures into its inner and outer networks' manifests (`evaluation`), where they
    ship (models: the folder holding mgn_inner/ and mgn_outer/; default the package's)."""
    from drape.runtime.layers import INNER_MODELS

    root = models or INNER_MODELS.parent
    written = []
    for key, entry in results["combinations"].items():
        inner, outer = key.split("+")
        for path in (root / "mgn_inner" / inner / "manifest.json", root / "mgn_outer" / f"{inner}_{outer}" / "manifest.json"):
            if not path.exists():
                continue
            manifest = json.loads(path.read_text())
            manifest["evaluation"] = {"thickness_m": results["thickness_m"], "frames": results["frames"], **entry}
            path.write_text(json.dumps(manifest, indent=2) + "\n")
            written.append(path)
    return written
