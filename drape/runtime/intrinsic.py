"""The intrinsic garment space (Wang et al. 2019) of trained garment templates, served with ONNX Runtime
(numpy + onnxruntime; no torch, no HTTP).

A model folder (written by `drape.export.intrinsic.export_intrinsic`) holds shape_encode.onnx (N_E),
shape_decode.onnx (N_D), encode.onnx (M_E + F_E: descriptor -> latent), decode.onnx (M_E + F_D: latent ->
descriptor), template.npz and manifest.json; `IntrinsicGarment` loads one (every file checked against the manifest's
sha256), `GarmentRegistry` every folder with a manifest.json under a root directory.

Everything the networks see is in a frame's *character space* (`drape.geometry.character_space`): the
world moved by minus the root (pelvis) position and turned by the inverse of the root's rotation. A
frame's motion window is the joint positions of that frame and the W frames before it (clamped at frame
0), in the frame's character space: it depends on frames 0..t only, so a keyframe encoded with the
motion cut after its frame sees the same window as the whole motion gives that frame.

Shapes and units: vertices (N, 3) / (T, N, 3) metres; poses (T, 24, 3) axis-angle radians (or (T, 72));
trans (T, 3) metres; latents (Z,) / (T, Z); windows (T, W + 1, 24, 3) metres; frames are 0-based
indices into the motion.
"""

from __future__ import annotations

import io
import json
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drape.assets.body import load_body
from drape.geometry.character_space import (
    character_space_numpy,
    motion_windows,
    root_frames,
    world_space_numpy,
)
from drape.geometry.skeleton import as_pose_array
from drape.runtime.model_files import checked_files, cpu_session

INTRINSIC_DIR = Path(__file__).resolve().parents[1] / "assets" / "models" / "intrinsic"
DECODE_BLOCK = 256  # frames decoded per ONNX Runtime call
REQUIRED_FILES = ("shape_encode", "shape_decode", "encode", "decode", "template")
# Seconds over which a shape keyframe's residual (what decoding its latent misses) fades: chosen on the intrinsic
# validation split among 10, 20 and 40 frames at 30 fps and no fading (docs/intrinsic.md).
KEYFRAME_FADE_S = 40 / 30


@dataclass(frozen=True)
class MotionFrames:
    """A motion's root frames, world space: joints (T, 24, 3) m, root_position (T, 3) m, root_rotation
    (T, 3, 3) (the pelvis' global rotation; columns are its axes); step: the motion's frames per frame of the
    model's fps (its fps / the model's), the spacing of a motion window's samples."""

    joints: np.ndarray
    root_position: np.ndarray
    root_rotation: np.ndarray
    step: float = 1.0

    def __len__(self) -> int:
        return len(self.joints)

    def windows(self, start: int, stop: int, window: int) -> np.ndarray:
        """The motion windows of frames start..stop-1: (stop - start, window + 1, 24, 3) float32 m, each in
        its frame's character space, its samples `step` frames apart (the model's window in seconds, whatever
        the motion's fps); equal to the rows start..stop-1 of `motion_windows` on the whole motion (computed on
        the frames from max(0, start - window * step) on only)."""
        lo = max(0, start - int(np.ceil(window * self.step)))
        w = motion_windows(self.joints[lo:stop], self.root_position[lo:stop], self.root_rotation[lo:stop], window,
                           self.step)
        return w[start - lo:]


def interpolate(keyframes: Sequence[tuple[int, np.ndarray]], num_frames: int) -> np.ndarray:
    """Latents of every frame from keyframes [(frame, latent (Z,)), ...] -> (num_frames, Z) float32.

    Linear between consecutive keyframes (sorted by frame here), held at the first keyframe's latent
    before it and at the last one's after it; a keyframe's own frame gets its latent exactly.
    ValueError for no keyframes, two keyframes on one frame, or latents of different sizes.
    """
    if not keyframes:
        raise ValueError("at least one keyframe is needed")
    ordered = sorted(keyframes, key=lambda k: int(k[0]))
    frames = np.array([int(f) for f, _ in ordered], dtype=np.int64)
    if np.any(np.diff(frames) == 0):
        dup = int(frames[1:][np.diff(frames) == 0][0])
        raise ValueError(f"two keyframes on frame {dup}")
    latents = [np.asarray(z, dtype=np.float64).reshape(-1) for _, z in ordered]
    if len({len(z) for z in latents}) != 1:
        raise ValueError(f"keyframe latents of different sizes: {sorted({len(z) for z in latents})}")
    lat = np.stack(latents)  # (K, Z)
    t = np.arange(num_frames)
    j = np.clip(np.searchsorted(frames, t, side="right") - 1, 0, len(frames) - 1)  # keyframe at or before t
    k = np.minimum(j + 1, len(frames) - 1)
    span = np.maximum(frames[k] - frames[j], 1)
    a = np.clip((t - frames[j]) / span, 0.0, 1.0)[:, None]  # 0 before the first keyframe: held at it
    out = lat[j] * (1.0 - a) + lat[k] * a
    return out.astype(np.float32)


def _bracketing(key_frames: np.ndarray, frames: np.ndarray, fade_frames: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each of `frames` (n,): the keyframes before and after it (indices j, k (n,) into key_frames; j == k
    before the first and after the last) and their weights (n,) each (see residual_weights)."""
    keys = np.asarray(key_frames, dtype=np.int64)
    t = np.asarray(frames, dtype=np.int64)
    j = np.clip(np.searchsorted(keys, t, side="right") - 1, 0, len(keys) - 1)  # keyframe at or before t
    k = np.minimum(j + 1, len(keys) - 1)
    span = np.maximum(keys[k] - keys[j], 1)
    a = np.clip((t - keys[j]) / span, 0.0, 1.0)  # 0 before the first keyframe, 1 after the last (k == j there)
    return (j, k, (1.0 - a) * np.exp(-np.abs(t - keys[j]) / fade_frames),
            a * np.exp(-np.abs(keys[k] - t) / fade_frames))


def residual_weights(key_frames: np.ndarray, frames: np.ndarray, fade_frames: float) -> np.ndarray:
    """Weights (n, K) of K keyframes' residuals at `frames` (n,) int: the linear interpolation weights of the
    keyframes before and after each frame (the nearest keyframe's weight 1 before the first and after the last),
    each times exp(-|frame - keyframe| / fade_frames). key_frames (K,) int, sorted, distinct; fade_frames > 0.
    A keyframe's own frame weighs it 1 and the others 0."""
    j, k, wj, wk = _bracketing(key_frames, frames, fade_frames)
    w = np.zeros((len(j), len(key_frames)))
    rows = np.arange(len(j))
    w[rows, j] += wj
    w[rows, k] += wk
    return w


@dataclass(frozen=True)
class KeyframeResidual:
    """What decoding leaves of the keyframes, added back so that each shape keyframe is met exactly at its frame
    and its correction fades away from it (`residual_weights`).

    frames (K,) int64 sorted; residuals (K, N, 3) float32 m, character space of each keyframe's frame (the
    keyframe's shape minus its decoded shape; zeros for keyframes given as latents); fade_frames > 0.
    """

    frames: np.ndarray
    residuals: np.ndarray
    fade_frames: float

    def at(self, start: int, stop: int) -> np.ndarray:
        """The residual of frames start..stop-1, (stop - start, N, 3) float32 m, character space."""
        j, k, wj, wk = _bracketing(self.frames, np.arange(start, stop), self.fade_frames)
        r = self.residuals
        return (wj.astype(np.float32)[:, None, None] * r[j] + wk.astype(np.float32)[:, None, None] * r[k])


class IntrinsicGarment:
    """The intrinsic space of one garment template: its two ONNX sessions, template, body and latent statistics.

    Attributes: name (the template's), body (the body preset it was trained on), vertices (N, 3) float32 m
    (rest pose on the body), faces (F, 3) int32, window (W past frames in a motion window), fps, version,
    latent_size (Z), latent_mean / latent_std (Z,) float64, keyframe_shrink (Z,) float64 in [0, 1] (how far a keyframe
    latent stays from latent_mean; all ones where the manifest has none), manifest (the whole manifest.json).
    """

    def __init__(self, model_dir: str | Path, threads: int = 2):
        self.path = Path(model_dir)
        self.manifest: dict[str, Any] = json.loads((self.path / "manifest.json").read_text())
        files = self.manifest.get("files", {})
        missing = [k for k in REQUIRED_FILES if k not in files]
        if missing:
            raise ValueError(f"{self.path}: the manifest lists no {', '.join(missing)} file")
        blobs = checked_files(self.path, self.manifest, files)
        self.sessions = {k: cpu_session(blobs[k], threads) for k, entry in files.items()
                         if str(entry["file"]).endswith(".onnx")}
        with np.load(io.BytesIO(blobs["template"]), allow_pickle=False) as z:
            self.vertices = np.ascontiguousarray(z["vertices"], dtype=np.float32)
            self.faces = np.ascontiguousarray(z["faces"], dtype=np.int32)
        for a in (self.vertices, self.faces):
            a.setflags(write=False)
        m = self.manifest
        self.name = str(m["template"])
        self.body = str(m.get("body", "neutral"))
        self.fps = float(m.get("fps", 30.0))
        self.version = str(m["version"])
        self.window = int(m["window"])
        cfg = m.get("model_config", {})
        self.latent_mean = np.asarray(m["latent_mean"], dtype=np.float64)
        self.latent_std = np.asarray(m["latent_std"], dtype=np.float64)
        self.latent_size = int(cfg.get("latent", len(self.latent_mean)))
        if self.latent_mean.shape != (self.latent_size,) or self.latent_std.shape != (self.latent_size,):
            raise ValueError(f"{self.path}: latent_mean / latent_std are not ({self.latent_size},)")
        # (Z,) in [0, 1]: how far each keyframe latent stays from latent_mean (drape.training.intrinsic_shrink);
        # a manifest without it keeps the encoder's latents
        self.keyframe_shrink = np.asarray(m.get("keyframe_shrink", np.ones(self.latent_size)), dtype=np.float64)
        if self.keyframe_shrink.shape != (self.latent_size,) or not np.all(
                (self.keyframe_shrink >= 0) & (self.keyframe_shrink <= 1)):
            raise ValueError(f"{self.path}: keyframe_shrink is not ({self.latent_size},) in [0, 1]")
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3 or \
                int(cfg.get("num_vertices", len(self.vertices))) != len(self.vertices):
            raise ValueError(f"{self.path}: template vertices {self.vertices.shape} do not match the model")
        body = load_body(self.body)
        self.rest_joints = body.joints.astype(np.float64)
        self.parents = body.parents

    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    @property
    def template_vertices(self) -> np.ndarray:
        """The template in rest pose on its body, (N, 3) float32 m (the same array as `vertices`)."""
        return self.vertices

    interpolate = staticmethod(interpolate)

    def _encode_local(self, vertices: np.ndarray, windows: np.ndarray) -> np.ndarray:
        """vertices (T, N, 3) float32 m and windows (T, W + 1, 24, 3) float32 m, character space -> latents (T, Z)."""
        return self.sessions["encode"].run(["latent"], {"descriptor": self.descriptors(vertices), "windows": windows})[0]

    def _decode_local(self, latents: np.ndarray, windows: np.ndarray) -> np.ndarray:
        """latents (T, Z) float32 and windows -> vertices (T, N, 3) float32 m, character space."""
        s = self.sessions["decode"].run(["descriptor"], {"latent": latents, "windows": windows})[0]
        return self.shapes(s)

    def descriptors(self, vertices: np.ndarray) -> np.ndarray:
        """N_E: shapes (K, N, 3) m in character space -> shape descriptors (K, D) float32."""
        return self.sessions["shape_encode"].run(["descriptor"], {"vertices": np.asarray(vertices, np.float32)})[0]

    def shapes(self, descriptors: np.ndarray) -> np.ndarray:
        """N_D: shape descriptors (K, D) -> shapes (K, N, 3) float32 m in character space."""
        return self.sessions["shape_decode"].run(["vertices"], {"descriptor": np.asarray(descriptors, np.float32)})[0]

    def motion_frames(self, poses: np.ndarray, trans: np.ndarray, fps: float | None = None) -> MotionFrames:
        """poses (T, 24, 3) or (T, 72) rad, trans (T, 3) m, at fps frames per second (None: the model's) -> the
        root frames on this garment's body, whose motion windows span the model's seconds (a motion at twice
        the model's fps is read every second frame; it was read frame by frame, as if twice as slow)."""
        joints, position, rotation = root_frames(as_pose_array(poses), np.asarray(trans, dtype=np.float64),
                                                 self.rest_joints, self.parents)
        step = 1.0 if fps is None else float(fps) / self.fps
        return MotionFrames(joints, position, rotation, step)

    def encode_at(self, vertices: np.ndarray, frames: Sequence[int], motion: MotionFrames) -> np.ndarray:
        """Keyframe shapes vertices (K, N, 3) m, world space at their frames (K,) of `motion` -> latents (K, Z)
        float32 (one ONNX Runtime call per DECODE_BLOCK keyframes: 10,000 keyframes in one call took 4 GB); each
        frame's window uses the motion up to that frame only. Each latent is the encoder's pulled toward the
        training mean: latent_mean + keyframe_shrink * (encoded - latent_mean) (the best guess of the garment's own
        latent from one frame; drape.training.intrinsic_shrink)."""
        v = np.asarray(vertices)
        idx = np.asarray(frames, dtype=np.int64).reshape(-1)
        if v.ndim != 3 or v.shape[1:] != (self.num_vertices, 3) or len(v) != len(idx):
            raise ValueError(f"expected ({len(idx)}, {self.num_vertices}, 3) vertices, got {v.shape}")
        if len(idx) and (idx.min() < 0 or idx.max() >= len(motion)):
            raise ValueError(f"frames must lie in [0, {len(motion) - 1}]")
        if not len(idx):
            return np.zeros((0, self.latent_size), np.float32)
        z = np.concatenate([self._encode_local(self._local_at(v[s:s + DECODE_BLOCK], idx[s:s + DECODE_BLOCK], motion),
                                               self._windows_at(idx[s:s + DECODE_BLOCK], motion))
                            for s in range(0, len(idx), DECODE_BLOCK)])
        if np.all(self.keyframe_shrink == 1):
            return z
        return (self.latent_mean + self.keyframe_shrink * (z.astype(np.float64) - self.latent_mean)).astype(np.float32)

    def _local_at(self, vertices: np.ndarray, idx: np.ndarray, motion: MotionFrames) -> np.ndarray:
        """Shapes (k, N, 3) m world space at frames idx (k,) of `motion` -> character space, (k, N, 3) float32."""
        v = np.asarray(vertices, dtype=np.float64)
        return character_space_numpy(v, motion.root_position[idx], motion.root_rotation[idx]).astype(np.float32)

    def _windows_at(self, idx: np.ndarray, motion: MotionFrames) -> np.ndarray:
        """The motion windows of frames idx (k,): (k, window + 1, 24, 3)."""
        return np.concatenate([motion.windows(int(f), int(f) + 1, self.window) for f in idx])

    def encode_frames(self, vertices: np.ndarray, poses: np.ndarray, trans: np.ndarray,
                      chunk: int = DECODE_BLOCK) -> np.ndarray:
        """Every frame of a garment sequence encoded: vertices (T, N, 3) m world space, poses (T, 24, 3) rad, trans
        (T, 3) m -> latents (T, Z) float32, `chunk` frames per ONNX Runtime call: the encoder's own latents (no
        keyframe_shrink; what the invariance statistics and the shrink's calibration measure)."""
        v = np.asarray(vertices, dtype=np.float64)
        if v.ndim != 3 or v.shape[1:] != (self.num_vertices, 3) or len(v) != len(poses):
            raise ValueError(f"expected ({len(poses)}, {self.num_vertices}, 3) vertices, got {v.shape}")
        motion = self.motion_frames(poses, trans)
        out = [np.zeros((0, self.latent_size), np.float32)]
        for s in range(0, len(v), chunk):
            e = min(s + chunk, len(v))
            local = character_space_numpy(v[s:e], motion.root_position[s:e], motion.root_rotation[s:e])
            out.append(self._encode_local(local.astype(np.float32), motion.windows(s, e, self.window)))
        return np.concatenate(out)

    def keyframe_placement(self, vertices_world: np.ndarray, poses: np.ndarray, trans: np.ndarray,
                           frame: int) -> tuple[float, float]:
        """How a keyframe shape sits against the template, both in character space (its frame's root frame; the
        template's at rest): (distance between their centroids, m; the shape's RMS spread about its centroid over
        the template's). A garment in world space at its frame gives a few cm and about 1; one left at the origin
        or kilometres away, or collapsed to a point, does not.

        vertices_world (N, 3) m; poses (T, 24, 3) rad and trans (T, 3) m: the motion; 0 <= frame < T."""
        motion = self.motion_frames(np.asarray(poses)[frame: frame + 1], np.asarray(trans)[frame: frame + 1])
        local = character_space_numpy(np.asarray(vertices_world, dtype=np.float64)[None], motion.root_position,
                                      motion.root_rotation)[0]
        rest = self.motion_frames(np.zeros((1, 24, 3)), np.zeros((1, 3)))
        template = character_space_numpy(self.vertices.astype(np.float64)[None], rest.root_position,
                                         rest.root_rotation)[0]
        spread = float(np.sqrt(((local - local.mean(0)) ** 2).sum(1).mean()))
        template_spread = float(np.sqrt(((template - template.mean(0)) ** 2).sum(1).mean()))
        return float(np.linalg.norm(local.mean(0) - template.mean(0))), spread / template_spread

    def encode(self, vertices_world: np.ndarray, poses: np.ndarray, trans: np.ndarray, frame: int,
               fps: float | None = None) -> np.ndarray:
        """A keyframe shape -> its latent (Z,) float32 (`encode_at`'s: pulled toward the mean by keyframe_shrink).

        vertices_world (N, 3) m: the garment at `frame`, world space; poses (T, 24, 3) rad and trans (T, 3) m:
        the motion (only frames 0..frame matter) at fps (None: the model's); frame: 0-based index, 0 <= frame < T.
        """
        if not 0 <= frame < len(poses):
            raise ValueError(f"frame {frame} is outside the motion's {len(poses)} frames")
        motion = self.motion_frames(np.asarray(poses)[: frame + 1], np.asarray(trans)[: frame + 1], fps)
        return self.encode_at(np.asarray(vertices_world)[None], [frame], motion)[0]

    def keyframe_residual(self, shapes: np.ndarray, shape_frames: Sequence[int], latent_frames: Sequence[int],
                          latents: np.ndarray, motion: MotionFrames, fps: float,
                          fade_s: float = KEYFRAME_FADE_S) -> KeyframeResidual:
        """The residual that makes a decoded stream meet its shape keyframes: shapes (Ks, N, 3) m world space at
        shape_frames (Ks,); latent_frames (Kl,) the frames of keyframes given as latents (residual 0); latents
        (T, Z) the stream's latents (each keyframe's own latent at its frame); fps of the motion; fade_s: the
        fading's time constant, seconds."""
        idx = np.asarray(shape_frames, dtype=np.int64).reshape(-1)
        v = np.asarray(shapes).reshape(len(idx), self.num_vertices, 3)
        frames = np.concatenate([idx, np.asarray(latent_frames, dtype=np.int64).reshape(-1)])
        order = np.argsort(frames, kind="stable")
        residuals = np.zeros((len(frames), self.num_vertices, 3), np.float32)  # latent keyframes: 0
        where = np.argsort(order, kind="stable")  # keyframe i's row in the frame order
        for s in range(0, len(idx), DECODE_BLOCK):  # DECODE_BLOCK shapes per ONNX Runtime call, as decode_chunks
            part = idx[s:s + DECODE_BLOCK]
            decoded = self._decode_local(np.ascontiguousarray(latents[part], dtype=np.float32),
                                         self._windows_at(part, motion))
            residuals[where[s:s + len(part)]] = self._local_at(v[s:s + len(part)], part, motion) - decoded
        return KeyframeResidual(frames[order], residuals, fade_s * float(fps))

    def decode_chunks(self, latents: np.ndarray, motion: MotionFrames, chunk: int = DECODE_BLOCK,
                      observe: Callable[[str, float], None] | None = None,
                      residual: KeyframeResidual | None = None) -> Iterator[np.ndarray]:
        """latents (T, Z), one per frame of `motion` -> world-space vertices, (n, N, 3) float32 m per chunk of
        up to `chunk` frames (one ONNX Runtime call each); `residual` (character space) added when given."""
        z = np.asarray(latents, dtype=np.float32)
        if z.ndim != 2 or z.shape != (len(motion), self.latent_size):
            raise ValueError(f"expected ({len(motion)}, {self.latent_size}) latents, got {z.shape}")
        for s in range(0, len(z), chunk):
            e = min(s + chunk, len(z))
            t = time.perf_counter()
            local = self._decode_local(np.ascontiguousarray(z[s:e]), motion.windows(s, e, self.window))
            if residual is not None:
                local = local + residual.at(s, e)
            if observe is not None:
                observe("intrinsic_decode", time.perf_counter() - t)
            yield world_space_numpy(local, motion.root_position[s:e].astype(np.float32),
                                    motion.root_rotation[s:e].astype(np.float32))

    def decode(self, latents: np.ndarray, poses: np.ndarray, trans: np.ndarray,
               chunk: int = DECODE_BLOCK, residual: KeyframeResidual | None = None,
               fps: float | None = None) -> np.ndarray:
        """latents (T, Z) and the motion (poses (T, 24, 3) rad, trans (T, 3) m, at fps; None: the model's) ->
        vertices (T, N, 3) float32 m, world space; decoded `chunk` frames per ONNX Runtime call, the root frames
        computed once; `residual` (from `keyframe_residual`) added in character space when given."""
        return self.decode_motion(latents, self.motion_frames(poses, trans, fps), chunk, residual)

    def decode_motion(self, latents: np.ndarray, motion: MotionFrames, chunk: int = DECODE_BLOCK,
                      residual: KeyframeResidual | None = None) -> np.ndarray:
        """`decode` for root frames already computed (`motion_frames`) -> vertices (T, N, 3) float32 m."""
        parts = list(self.decode_chunks(latents, motion, chunk, residual=residual))
        return np.concatenate(parts) if parts else np.zeros((0, self.num_vertices, 3), np.float32)

    def keyframed(self, shapes: np.ndarray, frames: Sequence[int], poses: np.ndarray, trans: np.ndarray,
                  fps: float, match_keyframes: bool = True, fade_s: float = KEYFRAME_FADE_S) -> np.ndarray:
        """Shape keyframes -> the whole stream: shapes (K, N, 3) m world space at frames (K,) of the motion (poses
        (T, 24, 3) rad, trans (T, 3) m, fps), encoded, their latents interpolated and decoded along the motion;
        with match_keyframes, each keyframe's residual is added back (`keyframe_residual`). -> (T, N, 3) float32."""
        motion = self.motion_frames(poses, trans, fps)
        z = self.encode_at(shapes, frames, motion)
        latents = self.interpolate(list(zip([int(f) for f in frames], z, strict=True)), len(motion))
        residual = self.keyframe_residual(shapes, frames, [], latents, motion, fps, fade_s) if match_keyframes else None
        return self.decode_motion(latents, motion, residual=residual)

    def sample(self, count: int, seed: int, frame: int, poses: np.ndarray,
               trans: np.ndarray, fps: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """`count` design candidates at `frame` of the motion (at fps; None: the model's): latents (count, Z)
        float32 = latent_mean + latent_std * standard normal (numpy default_rng(seed)), and their shapes (count,
        N, 3) float32 m, world space at that frame (decoded with that frame's motion window)."""
        if not 0 <= frame < len(poses):
            raise ValueError(f"frame {frame} is outside the motion's {len(poses)} frames")
        rng = np.random.default_rng(seed)
        z = (self.latent_mean + self.latent_std * rng.standard_normal((count, self.latent_size))).astype(np.float32)
        motion = self.motion_frames(np.asarray(poses)[: frame + 1], np.asarray(trans)[: frame + 1], fps)
        window = motion.windows(frame, frame + 1, self.window)
        local = self._decode_local(z, np.repeat(window, count, axis=0))
        rp = np.repeat(motion.root_position[frame:], count, axis=0)
        rr = np.repeat(motion.root_rotation[frame:], count, axis=0)
        return z, world_space_numpy(local.astype(np.float64), rp, rr).astype(np.float32)

    def info(self) -> dict[str, Any]:
        """What GET /v1/garments lists about this garment."""
        return {"name": self.name, "num_vertices": self.num_vertices, "num_faces": len(self.faces),
                "body": self.body, "models": ["intrinsic"], "fps": self.fps, "window": self.window,
                "version": self.version, "latent_size": self.latent_size}


class GarmentRegistry:
    """Every garment model under `root`: each subfolder holding a manifest.json, by template name. A missing or
    empty root gives no garments; two folders of one template name are an error."""

    def __init__(self, root: str | Path | None = INTRINSIC_DIR, threads: int = 2):
        self.root = Path(root) if root is not None else None
        self._garments: dict[str, IntrinsicGarment] = {}
        if self.root is None or not self.root.is_dir():
            return
        for sub in sorted(self.root.iterdir()):
            if not (sub / "manifest.json").is_file():
                continue
            g = IntrinsicGarment(sub, threads)
            if g.name in self._garments:
                raise ValueError(f"{sub}: garment {g.name!r} is already served from {self._garments[g.name].path}")
            self._garments[g.name] = g

    def get(self, name: str) -> IntrinsicGarment | None:
        return self._garments.get(name)

    def names(self) -> list[str]:
        return sorted(self._garments)

    def __iter__(self) -> Iterator[IntrinsicGarment]:
        return iter([self._garments[n] for n in self.names()])

    def __len__(self) -> int:
        return len(self._garments)

    def __contains__(self, name: object) -> bool:
        return name in self._garments

    def warm_up(self) -> None:
        """One frame decoded per garment, so the first request does not pay ORT's start-up."""
        for g in self:
            list(g.decode_chunks(g.latent_mean[None], g.motion_frames(np.zeros((1, 24, 3)), np.zeros((1, 3)))))


def garment_names(root: str | Path | None) -> list[str]:
    """The template names of the model folders under `root` (read from their manifests only; no model loaded)."""
    if root is None or not Path(root).is_dir():
        return []
    names = []
    for path in sorted(Path(root).glob("*/manifest.json")):
        try:
            names.append(str(json.loads(path.read_text())["template"]))
        except (OSError, ValueError, KeyError):
            continue
    return sorted(set(names))
