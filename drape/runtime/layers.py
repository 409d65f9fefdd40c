"""The served layer combinations (issue 22): an inner and an outer garment template worn together.

Each combination is one generated layered outfit (drape.assets.outfits.split_outfit: the outer built around the
inner, VERTICES together, a fixed seed) split into its two templates, on the neutral body. The inner layer is
posed by MGN's inner-layer network of its template (drape/assets/models/mgn_inner/<inner>/, `InnerModel`) where
one ships and its manifest says it measured better than DeePSD on the validation split (`served`), else by
DeePSD's served rig; the outer by MGN's outer-layer network of the combination (drape/assets/models/mgn_outer/
<inner>_<outer>/, `OuterModel`: a Transformer over windows of the motion that reads the inner network's keys and
the thickness) where one ships, is `served` and was trained beside the served inner network (its sha256), else
by DeePSD's served rig of that layer alone. A combination with an outer network serves the thicknesses it was
trained on.
The post step between layers (drape.geometry.layers) keeps the outer out of the inner. `inner_model`,
`outer_model` and `model` ("<inner_model>+<outer_model>", or the one name when both are the same) say what poses
them. The templates are made on first use (about 1.5 s each combination) and kept.

Shapes: template vertices (N, 3) float32 metres in rest pose on the body; faces (F, 3) int32.
"""

from __future__ import annotations

import io
import json
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drape.assets.outfits import split_outfit
from drape.runtime.deepsd import Rig
from drape.runtime.model_files import checked_files, cpu_session

COMBINATIONS = (("tshirt", "jacket"), ("tanktop", "longsleeve"))  # (inner, outer) garment types
VERTICES = 4000  # both layers together
SEED = 7
BODY = "neutral"
THICKNESS = (0.002, 0.02)  # metres: the inner thicknesses the post step between layers is served for
DEEPSD = "deepsd"  # DeePSD's served rig of the layer alone
MGN_INNER = "mgn_inner"  # MGN's inner-layer network of the template
MGN_OUTER = "mgn_outer"  # MGN's outer-layer network of the combination
INNER_MODELS = Path(__file__).resolve().parents[1] / "assets" / "models" / "mgn_inner"
OUTER_MODELS = Path(__file__).resolve().parents[1] / "assets" / "models" / "mgn_outer"
OUTER_BATCH = 64  # windows per ONNX Runtime call: 664 at once (10k frames) peak 4.3x 64 at a time (bench.layers_memory)
OUTER_FPS = 30.0  # frames/s an outer network's windows read where its manifest does not say (its config's mocap.fps)


def _network_folder(folder: str | Path, graph: str, threads: int) -> tuple[dict, Any, np.ndarray, np.ndarray, Rig]:
    """A layer network's folder (drape.export.layers), checked against its manifest's sha256 -> (manifest, the
    ONNX Runtime session of <graph>.onnx, template vertices (N, 3) m, faces (F, 3), Rig (weights, basis))."""
    folder = Path(folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    blobs = checked_files(folder, manifest, (graph, "rig"))
    with np.load(io.BytesIO(blobs["rig"]), allow_pickle=False) as z:
        rig = Rig(weights=z["weights"], blend_shapes=z["blend_shapes"])
        return manifest, cpu_session(blobs[graph], threads), z["vertices"], z["faces"], rig


class InnerModel:
    """MGN's inner-layer network of one template (drape.export.layers): pose.onnx (poses (T, 72) -> pose_keys
    (T, K)) and rig.npz (vertices (N, 3) m, faces, weights (N, 24), blend_shapes (K, N, 3) m), checked against
    the manifest's sha256. Posed like a DeePSD rig: drape.runtime.deepsd.pose_outfit(vertices, rig, keys, ...)."""

    def __init__(self, folder: str | Path, threads: int = 2):
        self.manifest, self.session, self.vertices, self.faces, self.rig = _network_folder(folder, "pose", threads)
        self.served = self.manifest["served"] == MGN_INNER
        self.sha256 = self.manifest["files"]["pose"]["sha256"]

    name = MGN_INNER

    def pose_keys(self, poses: np.ndarray) -> np.ndarray:
        """(T, 24, 3) or (T, 72) axis-angle rad -> (T, K) float32."""
        p = np.asarray(poses, np.float32).reshape(len(poses), 72)
        return self.session.run(["pose_keys"], {"poses": p})[0]


def window_starts(frames: int, window: int) -> tuple[np.ndarray, int]:
    """The windows an outer-layer network runs on: first frames (S,) at half-window stride, the last ending at
    the last frame, and their length (min(window, frames))."""
    if frames <= window:
        return np.zeros(1, np.int64), frames
    stride = max(window // 2, 1)
    starts = list(range(0, frames - window + 1, stride))
    if starts[-1] != frames - window:
        starts.append(frames - window)
    return np.asarray(starts, np.int64), window


def blend_windows(values: np.ndarray, starts: np.ndarray, frames: int) -> np.ndarray:
    """Per-window outputs (S, L, K) -> (frames, K) float32: each frame the mean of the windows covering it,
    weighted by a triangle over the window (its middle frames count most; no seam where windows change)."""
    length = values.shape[1]
    w = np.minimum(np.arange(1, length + 1), np.arange(length, 0, -1)).astype(np.float64)
    acc = np.zeros((frames, values.shape[2]))
    norm = np.zeros(frames)
    for s, v in zip(starts, values, strict=True):
        acc[s:s + length] += w[:, None] * v
        norm[s:s + length] += w
    return (acc / norm[:, None]).astype(np.float32)


class OuterModel:
    """MGN's outer-layer network of one combination (drape.export.layers.export_outer): outer.onnx ((motion
    (S, W, 78), thickness (S, 1) m, inner_keys (S, W, Ki)) -> outer_keys (S, W, K)) and rig.npz (vertices (No, 3)
    m, faces, weights (No, 24), blend_shapes (K, No, 3) m), checked against the manifest's sha256; `inner_sha256`
    is the inner network's pose.onnx it was trained beside (it reads that network's keys)."""

    def __init__(self, folder: str | Path, threads: int = 2):
        self.manifest, self.session, self.vertices, self.faces, self.rig = _network_folder(folder, "outer", threads)
        self.window = int(self.manifest["model_config"]["window"])
        self.inner_sha256 = self.manifest["inner_network"]["pose_sha256"]
        self.served = self.manifest["served"] == MGN_OUTER
        self.thickness = (float(self.manifest["config"]["thickness"][0]), float(self.manifest["config"]["thickness"][1]))
        # the simulations and clips it was trained on were all at this rate: a window is `window` frames of it
        self.fps = float(self.manifest["config"].get("mocap", {}).get("fps", OUTER_FPS))

    name = MGN_OUTER

    def pose_keys(self, poses: np.ndarray, trans: np.ndarray, fps: float, thickness: float, inner_keys: np.ndarray,
                  rest_joints: np.ndarray) -> np.ndarray:
        """poses (T, 24, 3) rad, trans (T, 3) m at fps frames/s, thickness H_in m, inner_keys (T, Ki) (the inner
        network's) -> (T, K) float32: `keys_of_features` of the motion's features.

        The network reads its windows at the rate it was trained at (`self.fps`): a motion at another rate is
        resampled to it first (slerp, drape.assets.motion.resample; the inner keys linearly), and the keys are
        interpolated back to the motion's frames (linearly; a last frame past the last resampled one, less than
        one model frame later, keeps its keys). At the model's rate nothing is resampled."""
        from drape.assets.motion import Motion, resample
        from drape.geometry.character_space import frames_at, motion_features
        from drape.geometry.skeleton import PARENTS

        if abs(float(fps) - self.fps) < 1e-6 or len(poses) < 2:
            return self.keys_of_features(motion_features(poses, trans, rest_joints, PARENTS, fps), thickness,
                                         inner_keys)
        at_model = resample(Motion(np.asarray(poses, np.float64).reshape(len(poses), 24, 3),
                                   np.asarray(trans, np.float64), float(fps)), self.fps)
        frames = np.arange(at_model.num_frames) * (float(fps) / self.fps)  # (n,) source frame of each sample
        keys = self.keys_of_features(motion_features(at_model.poses, at_model.trans, rest_joints, PARENTS, self.fps),
                                     thickness, frames_at(np.asarray(inner_keys, np.float64), frames))
        return frames_at(keys.astype(np.float64), np.arange(len(poses)) * (self.fps / float(fps))).astype(np.float32)

    def keys_of_features(self, features: np.ndarray, thickness: float, inner_keys: np.ndarray) -> np.ndarray:
        """features (T, 78) (`motion_features`), thickness H_in m, inner_keys (T, Ki) -> (T, K) float32: the
        motion's windows run in batches of up to OUTER_BATCH (the memory a call takes grows with its windows),
        blended (`blend_windows`)."""
        # as float32 once, not once per window
        features, inner_keys = np.asarray(features, np.float32), np.asarray(inner_keys, np.float32)
        starts, length = window_starts(len(features), self.window)
        out = np.concatenate([self.session.run(["outer_keys"], {
            "motion": np.stack([features[s:s + length] for s in batch]),
            "thickness": np.full((len(batch), 1), thickness, np.float32),
            "inner_keys": np.stack([inner_keys[s:s + length] for s in batch])})[0]
            for batch in np.array_split(starts, -(-len(starts) // OUTER_BATCH))])
        return blend_windows(out, starts, len(features))


def load_outer_model(inner: str, outer: str, folder: Path = OUTER_MODELS) -> OuterModel | None:
    """The combination's shipped outer-layer network, or None where none ships."""
    path = folder / f"{inner}_{outer}"
    return OuterModel(path) if (path / "manifest.json").exists() else None


def load_inner_model(name: str, folder: Path = INNER_MODELS) -> InnerModel | None:
    """The template's shipped inner-layer network, or None where none ships."""
    path = folder / name
    return InnerModel(path) if (path / "manifest.json").exists() else None


@dataclass(frozen=True)
class LayerTemplate:
    """One layer's template: name, role ('inner' | 'outer'), body, vertices (N, 3) float32 m, faces (F, 3) int32;
    network: the layer network that poses it (None: DeePSD's rig)."""

    name: str
    role: str
    body: str
    vertices: np.ndarray
    faces: np.ndarray
    network: InnerModel | OuterModel | None = field(default=None, compare=False)  # the served layer network, if any

    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    def info(self) -> dict:
        """The template's entry in GET /v1/garments."""
        return {"name": self.name, "num_vertices": self.num_vertices, "num_faces": int(len(self.faces)),
                "body": self.body, "models": [self.model]}

    @property
    def model(self) -> str:
        """What poses this layer: its network's name (MGN_INNER, MGN_OUTER) where one is served, else DEEPSD."""
        return self.network.name if self.network is not None else DEEPSD


@dataclass(frozen=True)
class LayerCombination:
    """An inner and an outer template worn together, and the inner thicknesses served, (min, max) m."""

    inner: LayerTemplate
    outer: LayerTemplate
    thickness: tuple[float, float] = THICKNESS

    @property
    def model(self) -> str:
        a, b = self.inner.model, self.outer.model
        return a if a == b else f"{a}+{b}"


def _same_template(network: InnerModel | OuterModel, vertices: np.ndarray, faces: np.ndarray) -> bool:
    return (network.vertices.shape == vertices.shape and np.allclose(network.vertices, vertices, atol=1e-6)
            and np.array_equal(network.faces, faces))


class LayerCatalog:
    """The served combinations (COMBINATIONS), made on first use; thread-safe."""

    def __init__(self, combinations: tuple[tuple[str, str], ...] = COMBINATIONS, models: Path = INNER_MODELS,
                 outer_models: Path = OUTER_MODELS):
        self._kinds = combinations
        self._models = models
        self._outer_models = outer_models
        self._made: list[LayerCombination] | None = None
        self._lock = threading.Lock()

    def combinations(self) -> list[LayerCombination]:
        with self._lock:
            if self._made is None:
                made = []
                for inner, outer in self._kinds:
                    (vi, fi), (vo, fo) = split_outfit(f"{inner},{outer}", VERTICES, seed=SEED, body=BODY)
                    network = load_inner_model(inner, self._models)
                    if network is not None and not _same_template(network, vi, fi):
                        raise ValueError(f"the {inner} inner-layer network was trained on another template")
                    served = network if network is not None and network.served else None
                    top = load_outer_model(inner, outer, self._outer_models)
                    if top is not None and not _same_template(top, vo, fo):
                        raise ValueError(f"the {inner}+{outer} outer-layer network was trained on another template")
                    # the outer network reads the inner network's keys: served only beside the one it was trained with
                    top = top if top is not None and top.served and served is not None and \
                        top.inner_sha256 == served.sha256 else None
                    made.append(LayerCombination(LayerTemplate(inner, "inner", BODY, vi, fi, served),
                                                 LayerTemplate(outer, "outer", BODY, vo, fo, top),
                                                 top.thickness if top is not None else THICKNESS))
                self._made = made
            return self._made

    def templates(self) -> list[LayerTemplate]:
        """Every served layer template, once each, in the combinations' order."""
        seen: dict[str, LayerTemplate] = {}
        for c in self.combinations():
            for t in (c.inner, c.outer):
                seen.setdefault(t.name, t)
        return list(seen.values())

    def template(self, name: str) -> LayerTemplate | None:
        return next((t for t in self.templates() if t.name == name), None)

    def find(self, inner: str, outer: str) -> LayerCombination | None:
        return next((c for c in self.combinations() if c.inner.name == inner and c.outer.name == outer), None)
