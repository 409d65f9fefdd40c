"""The serving engine: the DeePSD model, an outfit rig cache, chunked posing (numpy + ORT only)."""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.geometry.refine import BodySurface, Refiner, RefineReport
from drape.runtime.cache import LRUBytesCache
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, Rig, pose_outfit


@dataclass(frozen=True)
class RiggedOutfit:
    """An outfit in rest pose with its rig: vertices (N, 3) float32 m, faces (F, 3) int32."""

    outfit_id: str
    body: str
    vertices: np.ndarray
    faces: np.ndarray
    rig: Rig

    @property
    def nbytes(self) -> int:
        return self.vertices.nbytes + self.faces.nbytes + self.rig.weights.nbytes + self.rig.blend_shapes.nbytes


@dataclass(frozen=True)
class RefineSettings:
    """eps: metres kept from the body surface; max_iterations: fast-path iterations per frame;
    relief_iterations: rounds of the stretch relief pass (0: none)."""

    eps: float = 0.003
    max_iterations: int = 3
    relief_iterations: int = 0

    def refiner(self, faces: np.ndarray, num_vertices: int) -> Refiner:
        return Refiner(faces, num_vertices, eps=self.eps, max_iterations=self.max_iterations,
                       relief_iterations=self.relief_iterations)


@lru_cache(maxsize=8)
def body_surface(body: str) -> BodySurface:
    b = load_body(body)
    return BodySurface(b.faces, len(b.vertices))


def refine_frames(frames: np.ndarray, faces: np.ndarray, body: str, poses: np.ndarray, translation: np.ndarray,
                  refiner: Refiner) -> np.ndarray:
    """Refine posed garment frames (n, N, 3) against the body posed by (poses, translation): (n, N, 3) float32."""
    posed_body = load_body(body).pose(poses, translation).astype(np.float64)
    surface = body_surface(body)
    report = RefineReport()
    return np.stack([refiner.refine_frame(f, b, surface, report) for f, b in zip(frames, posed_body, strict=True)]
                    ).astype(np.float32)


class Engine:
    """Loads the model once; rigs outfits (cached by content) and poses them chunk by chunk."""

    def __init__(self, model_dir: str | Path = MODEL_DIR, threads: int = 2, cache_bytes: int = 512 * 2**20,
                 observe: Callable[[str, float], None] | None = None):
        self.model = DeePSDModel(model_dir, threads=threads)
        self.cache: LRUBytesCache[RiggedOutfit] = LRUBytesCache(cache_bytes)
        self._observe = observe or (lambda stage, seconds: None)
        files = self.model.manifest["files"]
        self.model_tag = f"deepsd-{self.model.manifest['version']}-{files['outfit']['sha256'][:16]}"

    def outfit_id(self, vertices: np.ndarray, faces: np.ndarray, body: str) -> str:
        """Content hash of the canonical mesh (float32 vertices, int32 faces), the body and the model."""
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(vertices, dtype="<f4").tobytes())
        h.update(np.ascontiguousarray(faces, dtype="<i4").tobytes())
        h.update(f"|{body}|{self.model_tag}".encode())
        return h.hexdigest()[:32]

    def rig(self, vertices: np.ndarray, faces: np.ndarray, body: str) -> RiggedOutfit:
        v = np.ascontiguousarray(vertices, dtype=np.float32)
        f = np.ascontiguousarray(faces, dtype=np.int32)
        oid = self.outfit_id(v, f, body)
        cached = self.cache.get(oid)
        if cached is not None:
            return cached
        t = time.perf_counter()
        rig = self.model.rig(v, f)
        self._observe("outfit", time.perf_counter() - t)
        out = RiggedOutfit(oid, body, v, f, rig)
        self.cache.put(oid, out)
        return out

    def lookup(self, outfit_id: str) -> RiggedOutfit | None:
        return self.cache.get(outfit_id)

    def pose_chunks(self, outfit: RiggedOutfit, poses: np.ndarray, translation: np.ndarray,
                    chunk: int = 32, refine: RefineSettings | None = None) -> Iterator[np.ndarray]:
        """Posed vertices in chunks of up to `chunk` frames: (n, N, 3) float32 each, refined if asked."""
        joints = load_body(outfit.body).joints
        refiner = refine.refiner(outfit.faces, len(outfit.vertices)) if refine else None
        for start in range(0, len(poses), chunk):
            p, tr = poses[start : start + chunk], translation[start : start + chunk]
            t = time.perf_counter()
            keys = self.model.pose_keys(p)
            self._observe("pose", time.perf_counter() - t)
            t = time.perf_counter()
            frames = pose_outfit(outfit.vertices, outfit.rig, keys, joints, p, tr)
            self._observe("posing", time.perf_counter() - t)
            if refiner is not None:
                t = time.perf_counter()
                frames = refine_frames(frames, outfit.faces, outfit.body, p, tr, refiner)
                self._observe("refine", time.perf_counter() - t)
            yield frames

    def refine_chunks(self, vertices: np.ndarray, faces: np.ndarray, body: str, poses: np.ndarray,
                      translation: np.ndarray, options: RefineSettings, chunk: int = 32) -> Iterator[np.ndarray]:
        """A given garment stream (T, N, 3), refined against the body in chunks: (n, N, 3) float32 each."""
        refiner = options.refiner(faces, vertices.shape[1])
        for start in range(0, len(vertices), chunk):
            t = time.perf_counter()
            s = slice(start, start + chunk)
            yield refine_frames(vertices[s], faces, body, poses[s], translation[s], refiner)
            self._observe("refine", time.perf_counter() - t)

    def warm_up(self) -> None:
        """One small rig and pose, so the first request does not pay ORT's start-up."""
        v = np.array([[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2], [0.1, 1.1, 0.25]], dtype=np.float32)
        f = np.array([[0, 1, 2], [1, 3, 2]], dtype=np.int32)
        rig = self.model.rig(v, f)
        outfit = RiggedOutfit("warm-up", "neutral", v, f, rig)
        for _ in self.pose_chunks(outfit, np.zeros((2, 24, 3)), np.zeros((2, 3))):
            pass
