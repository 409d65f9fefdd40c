"""The serving engine: the DeePSD model, an outfit rig cache, chunked posing, and the intrinsic garment
models (`drape.runtime.intrinsic`) with their chunked decoding (numpy + ORT only).

Refinement of a chunk of frames is split over `refine_workers` processes (frames are refined
independently, so the result is the same as in one process): on the 2-core machine a 6k-vertex
stream refines 1.4-1.7x faster with 2 (bench/refine_parallel.py, docs/refine.md).
"""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from drape.assets.body import Body, has_body, list_bodies, load_body
from drape.geometry.layers import LayerRefiner
from drape.geometry.lbs import rest_space_offsets
from drape.geometry.mesh import coincident_groups, regroup_faces
from drape.geometry.refine import (
    EPS,
    FAR_K,
    MAX_ITERATIONS,
    RELIEF_ITERATIONS,
    BodySurface,
    Refiner,
    RefineReport,
)
from drape.geometry.skeleton import PARENTS, forward_kinematics
from drape.runtime.cache import LRUBytesCache
from drape.runtime.collision_fit import Frames, served_fit_frames, served_rig
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, Rig, pose_outfit
from drape.runtime.intrinsic import (
    DECODE_BLOCK,
    INTRINSIC_DIR,
    GarmentRegistry,
    IntrinsicGarment,
    KeyframeResidual,
)
from drape.runtime.layers import (
    InnerModel,
    LayerCatalog,
    LayerCombination,
    LayerTemplate,
    OuterModel,
)
from drape.runtime.sparse_rig import INFLUENCES

POSE_BLOCK = 128  # frames posed per call (then handed out a chunk at a time)


@dataclass(frozen=True)
class RiggedOutfit:
    """An outfit in rest pose with its rig: vertices (N, 3) float32 m, faces (F, 3) int32."""

    outfit_id: str
    body: str
    vertices: np.ndarray
    faces: np.ndarray
    rig: Rig
    influences: int = 24  # skin weights per vertex at most (the served rigs: 4 or 8)
    diagnostics: dict | None = None  # where the mesh sits on the body at rest (drape.geometry.placement)
    fit: dict | None = None  # with rig's fit: the fitted mesh, transform and report (POST /v1/outfits/fit's answer)
    parts: list[dict] | None = None  # the mesh file's named parts: [{"name", "start", "stop"}] vertex ranges
    uv_corners: np.ndarray | None = None  # (F, 3, 2) float32: the mesh file's texture coordinates, for its GLBs

    @property
    def nbytes(self) -> int:
        uv = 0 if self.uv_corners is None else self.uv_corners.nbytes
        return self.vertices.nbytes + self.faces.nbytes + self.rig.weights.nbytes + self.rig.blend_shapes.nbytes + uv


@dataclass(frozen=True)
class RefineSettings:
    """eps: metres kept from the body surface; max_iterations: fast-path iterations per frame;
    relief_iterations: rounds of the stretch relief pass (0: none)."""

    eps: float = EPS
    max_iterations: int = MAX_ITERATIONS
    relief_iterations: int = RELIEF_ITERATIONS

    def refiner(self, faces: np.ndarray, num_vertices: int, rest: np.ndarray | None = None) -> Refiner:
        """The body refinement of one topology; with the garment's rest shape (N, 3) m, the edge-limit pass takes
        the relief pass's place (refine.Refiner's `rest`)."""
        return Refiner(faces, num_vertices, eps=self.eps, max_iterations=self.max_iterations,
                       relief_iterations=self.relief_iterations, rest=rest)


@dataclass(frozen=True)
class InnerStream:
    """A garment worn under a refined one: vertices (T, Ni, 3) float32 m, faces (Fi, 3) int32, thickness m."""

    vertices: np.ndarray
    faces: np.ndarray
    thickness: float


@lru_cache(maxsize=4)
def cached_layer_refiner(settings: RefineSettings, inner_faces: bytes, num_inner: int, outer_faces: bytes,
                         num_outer: int, thickness: float, body: tuple[str, bytes | None, int],
                         ) -> tuple[LayerRefiner, threading.Lock]:
    """This process's LayerRefiner for two topologies (faces: (F, 3) int32 as bytes), a thickness and a body
    (`_surface_arguments`: a worker process knows only the presets by name), and the lock to hold while using it:
    its surfaces keep the frame being refined (the posed inner layer), so two threads of the serving process must
    not refine with it at once."""
    name, faces, count = body
    if faces is None:
        b = load_body(name)
        body_faces, count = b.faces, len(b.vertices)
    else:
        body_faces = np.frombuffer(faces, dtype=np.int32).reshape(-1, 3)
    return LayerRefiner(np.frombuffer(inner_faces, dtype=np.int32).reshape(-1, 3), num_inner,
                        np.frombuffer(outer_faces, dtype=np.int32).reshape(-1, 3), num_outer, thickness,
                        body_faces, count, eps=settings.eps, max_iterations=settings.max_iterations,
                        relief_iterations=settings.relief_iterations), threading.Lock()


def refine_layer_frames(refiner: LayerRefiner, inner: np.ndarray, outer: np.ndarray, body_vertices: np.ndarray,
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Two layers' frames inner (n, Ni, 3), outer (n, No, 3) through the post step between layers against the
    posed body's vertices (n, M, 3) -> (inner, outer) float32."""
    pairs = [refiner.refine_frame(i, o, b, None) for i, o, b in zip(inner, outer, body_vertices, strict=True)]
    return np.stack([p[0] for p in pairs]).astype(np.float32), np.stack([p[1] for p in pairs]).astype(np.float32)


def _refine_layers_in_worker(inner: np.ndarray, inner_faces: bytes, outer: np.ndarray, outer_faces: bytes,
                             thickness: float, body: tuple[str, bytes | None, int], body_vertices: np.ndarray,
                             settings: RefineSettings) -> tuple[np.ndarray, np.ndarray]:
    """`refine_layer_frames` in a worker process (body: `_surface_arguments`)."""
    refiner, lock = cached_layer_refiner(settings, inner_faces, inner.shape[1], outer_faces, outer.shape[1],
                                         thickness, body)
    with lock:
        return refine_layer_frames(refiner, inner, outer, body_vertices)


@lru_cache(maxsize=8)
def body_surface(body: str, faces: bytes | None = None, num_vertices: int = 0) -> BodySurface:
    """The body's collision surface, built once per process. A worker process does not know the user
    bodies registered in the serving process: it is given their faces ((F, 3) int32 as bytes) and vertex
    count instead (a user body's name is a hash of its content, so the name keys the cache safely)."""
    if faces is None:
        b = load_body(body)
        return BodySurface(b.faces, len(b.vertices), far_k=FAR_K)
    return BodySurface(np.frombuffer(faces, dtype=np.int32).reshape(-1, 3), num_vertices, far_k=FAR_K)


def resolved_body(body: str | Body) -> Body:
    """A body given by name (looked up now) or already resolved. A request resolves its body once and passes the
    Body on, so that a user body DELETEd while its answer streams (drape.runtime.body_store) still finishes it."""
    return body if isinstance(body, Body) else load_body(body)


def _surface_arguments(body: str | Body) -> tuple[str, bytes | None, int]:
    """What a worker needs to build `body`'s surface: presets by name, any other body (a user body, which a
    worker cannot load, and which may be deleted from this process by now) by its faces and vertex count."""
    b = resolved_body(body)
    if b.name in list_bodies() and b is load_body(b.name):
        return b.name, None, 0
    return b.name, np.ascontiguousarray(b.faces, dtype=np.int32).tobytes(), len(b.vertices)


def posed_body(body: str | Body, poses: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """The body's vertices posed by (poses (n, 24, 3) or (n, 72), translation (n, 3)): (n, M, 3) float64, m."""
    return resolved_body(body).pose(poses, translation).astype(np.float64)


def refine_against(frames: np.ndarray, surface: BodySurface, body_vertices: np.ndarray, refiner: Refiner) -> np.ndarray:
    """Refine garment frames (n, N, 3) against posed body vertices (n, M, 3) of the body whose surface is
    given: (n, N, 3) float32."""
    report = RefineReport()
    return np.stack([refiner.refine_frame(f, b, surface, report) for f, b in zip(frames, body_vertices, strict=True)]
                    ).astype(np.float32)


@lru_cache(maxsize=4)
def cached_refiner(settings: RefineSettings, faces: bytes, num_vertices: int, rest: bytes | None = None) -> Refiner:
    """This process's Refiner for one garment topology, settings and rest shape (faces: (F, 3) int32 as bytes;
    rest: (N, 3) float64 m as bytes, or None), built once."""
    shape = None if rest is None else np.frombuffer(rest, dtype=np.float64).reshape(num_vertices, 3)
    return settings.refiner(np.frombuffer(faces, dtype=np.int32).reshape(-1, 3), num_vertices, shape)


def _refine_in_worker(frames: np.ndarray, faces: bytes, body: tuple[str, bytes | None, int], body_vertices: np.ndarray,
                      settings: RefineSettings, rest: bytes | None = None) -> np.ndarray:
    """`refine_against` in a worker process (body: `_surface_arguments`): (n, N, 3) float32."""
    return refine_against(frames, body_surface(*body), body_vertices,
                          cached_refiner(settings, faces, frames.shape[1], rest))


def _exit_with(server_pid: int, period_s: float = 0.5) -> None:
    """A worker's initializer: a daemon thread ends this process once `server_pid` is gone, so that no
    worker outlives the serving process, even one killed by SIGKILL or the OOM killer."""

    def watch() -> None:
        while True:
            time.sleep(period_s)
            try:
                os.kill(server_pid, 0)
            except ProcessLookupError:
                os._exit(0)
            except PermissionError:  # pragma: no cover - the pid was reused by another user's process
                os._exit(0)

    threading.Thread(target=watch, name="exit-with-server", daemon=True).start()


def _start_worker() -> None:
    """A worker's first task: load the neutral body's surface, and stay busy long enough that each
    worker gets one of these tasks (an idle worker would take a second)."""
    body_surface("neutral")
    time.sleep(0.2)


class RefinePool:
    """Refines a chunk's frames split over `workers` processes; fewer than `min_frames` per worker: in process.

    The processes start at `start()` (the engine's warm-up) or on first use, from a fork server (not
    forked from the serving process, whose ONNX Runtime threads a fork would copy in an unknown state);
    close() stops them, and each exits by itself when the serving process is gone (`_exit_with`). If a worker dies, the chunk is refined in process and the next one starts new workers.
    """

    def __init__(self, workers: int, min_frames: int = 2):
        self.workers, self.min_frames = workers, min_frames
        self._pool: Executor | None = None
        self._lock = threading.Lock()

    def refine(self, frames: np.ndarray, faces: np.ndarray, body: str | Body, poses: np.ndarray,
               translation: np.ndarray, settings: RefineSettings, rest: np.ndarray | None = None) -> np.ndarray:
        """frames (n, N, 3), faces (F, 3), body (a name or a resolved Body), poses (n, 24, 3) or (n, 72), translation
        (n, 3) -> refined (n, N, 3) float32. Vertices that coincide in every frame (UV seams; within 1 um) are
        refined as one and stay together. rest: the garment's rest shape (N, 3) m, where it has one (an outfit drape
        rigged): edges are then kept near their rest lengths (`RefineSettings.refiner`)."""
        body = resolved_body(body)
        first, group = coincident_groups(np.ascontiguousarray(np.asarray(frames).transpose(1, 0, 2)).reshape(
            frames.shape[1], -1))
        if len(first) < frames.shape[1]:
            return self.refine(frames[:, first], regroup_faces(faces, group), body, poses, translation,
                               settings, None if rest is None else np.asarray(rest)[first])[:, group]
        # the body is posed here, for the whole chunk, in every case: posing in smaller batches would
        # change its vertices in the last float bit, and the refinement's discrete choices with them
        vertices = posed_body(body, poses, translation)
        f = np.ascontiguousarray(faces, dtype=np.int32).tobytes()
        surface = _surface_arguments(body)
        r = None if rest is None else np.ascontiguousarray(rest, dtype=np.float64).tobytes()
        done = self._over_workers(len(frames), lambda i: (_refine_in_worker, frames[i], f, surface, vertices[i],
                                                          settings, r))
        if done is not None:
            return np.concatenate(done)
        return refine_against(frames, body_surface(*surface), vertices, cached_refiner(settings, f, frames.shape[1], r))

    def refine_layers(self, inner: np.ndarray, inner_faces: np.ndarray, outer: np.ndarray, outer_faces: np.ndarray,
                      thickness: float, body: str | Body, poses: np.ndarray, translation: np.ndarray,
                      settings: RefineSettings) -> tuple[np.ndarray, np.ndarray]:
        """Two layers' frames, inner (n, Ni, 3) and outer (n, No, 3) with their faces, through the post step
        between layers (drape.geometry.layers; thickness: H_in, m) against `body` posed by (poses, translation),
        split over the workers as `refine` splits a garment's frames -> (inner, outer) float32."""
        body = resolved_body(body)
        vertices = posed_body(body, poses, translation)
        fi = np.ascontiguousarray(inner_faces, dtype=np.int32).tobytes()
        fo = np.ascontiguousarray(outer_faces, dtype=np.int32).tobytes()
        surface = _surface_arguments(body)
        done = self._over_workers(len(outer), lambda i: (_refine_layers_in_worker, inner[i], fi, outer[i], fo,
                                                         thickness, surface, vertices[i], settings))
        if done is not None:
            return np.concatenate([d[0] for d in done]), np.concatenate([d[1] for d in done])
        return _refine_layers_in_worker(inner, fi, outer, fo, thickness, surface, vertices, settings)

    def _over_workers(self, frames: int, task: Callable[[np.ndarray], tuple]) -> list | None:
        """Split `frames` frame indices over the workers: task(indices) -> (function, *arguments) for one part;
        -> each part's result in order, or None where the frames stay in this process (fewer than `min_frames`
        per worker, one worker, or a worker died: the pool is closed and the next call starts new ones)."""
        parts = min(self.workers, frames // self.min_frames)
        if parts < 2:
            return None
        pool = self.start()
        try:
            futures = [pool.submit(*task(i)) for i in np.array_split(np.arange(frames), parts)]
            return [fut.result() for fut in futures]
        except BrokenProcessPool:  # drop that pool only: another request may have started new workers since
            with self._lock:
                if self._pool is pool:
                    self._pool = None
            pool.shutdown(cancel_futures=True)
            return None

    def start(self) -> Executor:
        """Start the worker processes now if they are not running (each loads the geometry code and the
        neutral body), so that the first request does not wait for them."""
        with self._lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("forkserver"),
                                                 initializer=_exit_with, initargs=(os.getpid(),))
                for fut in [self._pool.submit(_start_worker) for _ in range(self.workers)]:
                    fut.result()
            return self._pool

    def close(self) -> None:
        with self._lock:
            if self._pool is not None:
                self._pool.shutdown(cancel_futures=True)
                self._pool = None


class Engine:
    """Loads the models once; rigs outfits (cached by content) and poses them chunk by chunk; decodes the
    intrinsic garments' latents (`garments`: every model folder under `intrinsic_dir`, none if it is missing)."""

    def __init__(self, model_dir: str | Path = MODEL_DIR, threads: int = 2, cache_bytes: int = 512 * 2**20,
                 observe: Callable[[str, float], None] | None = None, refine_workers: int = 1,
                 intrinsic_dir: str | Path | None = INTRINSIC_DIR, collision_fit: bool = True):
        """collision_fit: the served rig's blend shapes are fit to keep the garment out of its body
        (drape.runtime.collision_fit); False serves the 4- (or 8-) influence rig of the network as it is."""
        self.model = DeePSDModel(model_dir, threads=threads)
        self.garments = GarmentRegistry(intrinsic_dir, threads=threads)
        self.layers = LayerCatalog()
        self.refine_pool = RefinePool(refine_workers)
        self.cache: LRUBytesCache[RiggedOutfit] = LRUBytesCache(cache_bytes)
        self._observe = observe or (lambda stage, seconds: None)
        files = self.model.manifest["files"]
        self.model_tag = f"deepsd-{self.model.manifest['version']}-{files['outfit']['sha256'][:16]}"
        self.collision_fit = collision_fit
        self._frames: tuple[Frames, Frames] | None = None  # what the served rig fits on (served_fit_frames), made once

    def served_frames(self) -> tuple[Frames, Frames]:
        """The sparse rig's and the collision fit's poses (T, 24, 3) and pose keys (T, P), made once."""
        if self._frames is None:
            self._frames = served_fit_frames(self.model.pose_keys)
        return self._frames

    def fit_frames(self) -> Frames:
        """The sparse rig's fit poses and their pose keys."""
        return self.served_frames()[0]

    def collision_frames(self) -> Frames | None:
        """The collision fit's poses and their pose keys; None when it is off."""
        return self.served_frames()[1] if self.collision_fit else None

    def outfit_id(self, vertices: np.ndarray, faces: np.ndarray, body: str, influences: int = 4,
                  uv_corners: np.ndarray | None = None) -> str:
        """Content hash of the canonical mesh (float32 vertices, int32 faces, and their shapes), the body, the rig's
        influences per vertex and the model; and of the texture coordinates (F, 3, 2) when given (the same garment
        with other UVs is another outfit: its GLBs differ)."""
        h = hashlib.sha256()
        v, f = np.ascontiguousarray(vertices, dtype="<f4"), np.ascontiguousarray(faces, dtype="<i4")
        h.update(f"{v.shape}{f.shape}".encode())  # where the vertices' bytes end and the faces' begin
        h.update(v.tobytes())
        h.update(f.tobytes())
        h.update(f"|{body}|{self.model_tag}|i{influences}|c{int(self.collision_fit)}".encode())
        if uv_corners is not None:
            h.update(b"|uv" + np.ascontiguousarray(uv_corners, dtype="<f4").tobytes())
        return h.hexdigest()[:32]

    def rig(self, vertices: np.ndarray, faces: np.ndarray, body: str, influences: int = 4,
            uv_corners: np.ndarray | None = None) -> RiggedOutfit:
        """The served rig of an outfit: at most `influences` (4 or 8) skin weights per vertex, blend shapes
        refit for them (drape.runtime.sparse_rig) and to keep the garment out of the body
        (drape.runtime.collision_fit); cached by content. uv_corners (F, 3, 2): the mesh's texture coordinates,
        kept with the rig (they do not change it: the rig of the same mesh without them is reused)."""
        if influences not in INFLUENCES:
            raise ValueError(f"influences must be one of {INFLUENCES}, got {influences}")
        v = np.ascontiguousarray(vertices, dtype=np.float32)
        f = np.ascontiguousarray(faces, dtype=np.int32)
        uv = None if uv_corners is None else np.ascontiguousarray(uv_corners, dtype=np.float32)
        if uv is not None and uv.shape != (len(f), 3, 2):
            raise ValueError(f"uv_corners must be (F, 3, 2) = ({len(f)}, 3, 2), got {uv.shape}")
        if uv is not None:
            key = self.outfit_id(v, f, body, influences, uv)
            cached = self.cache.get(key)
            if cached is not None:
                return cached
            plain = self.rig(v, f, body, influences)
            out = replace(plain, outfit_id=key, uv_corners=uv)
            self.cache.put(key, out)
            return out
        oid = self.outfit_id(v, f, body, influences)
        cached = self.cache.get(oid)
        if cached is not None:
            return cached
        t = time.perf_counter()
        body_mesh = load_body(body)
        dense = self.model.rig(v, f, body_mesh)
        self._observe("outfit", time.perf_counter() - t)
        t = time.perf_counter()
        rig = served_rig(v, dense, body_mesh, influences, self.fit_frames(), self.collision_frames(), faces=f)
        self._observe("sparse_rig", time.perf_counter() - t)
        out = RiggedOutfit(oid, body, v, f, rig, influences)
        self.cache.put(oid, out)
        return out

    def lookup(self, outfit_id: str) -> RiggedOutfit | None:
        """The rigged outfit of `outfit_id`, or None: not cached, or its body is no longer held (a user body
        deleted since; posing needs its joints). The same body registered again finds it again."""
        outfit = self.cache.get(outfit_id)
        if outfit is None or not has_body(outfit.body):
            return None
        return outfit

    def missing_body_of(self, outfit_id: str) -> str | None:
        """The body an outfit was rigged on when it is still cached but that body is no longer held (`lookup`
        gives None for it), else None."""
        outfit = self.cache.get(outfit_id)
        return outfit.body if outfit is not None and not has_body(outfit.body) else None

    def pose_chunks(self, outfit: RiggedOutfit, poses: np.ndarray, translation: np.ndarray,
                    chunk: int = 32, refine: RefineSettings | None = None,
                    pose_keys: Callable[[np.ndarray], np.ndarray] | None = None,
                    body: Body | None = None) -> Iterator[np.ndarray]:
        """Posed vertices in chunks of up to `chunk` frames: (n, N, 3) float32 each, refined if asked.

        Posing runs POSE_BLOCK frames per call (a 32-frame call re-packs the blend shapes for its GEMM
        and poses ~1.5x slower a frame: bench/pose.py) and the block is handed out `chunk` frames at a time.
        pose_keys: poses (n, 24, 3) -> the rig's keys (n, P); default DeePSD's pose network.
        body: the outfit's body as the request resolved it; default looked up by `outfit.body` when the first
        chunk is asked for, once: every chunk is posed and refined on that Body, even if it is deleted meanwhile.
        """
        body = body if body is not None else load_body(outfit.body)
        joints = body.joints
        keys_of = pose_keys or self.model.pose_keys
        block = max(chunk, POSE_BLOCK)
        for start in range(0, len(poses), block):
            p, tr = poses[start : start + block], translation[start : start + block]
            t = time.perf_counter()
            keys = keys_of(p)
            self._observe("pose", time.perf_counter() - t)
            t = time.perf_counter()
            frames = pose_outfit(outfit.vertices, outfit.rig, keys, joints, p, tr)
            self._observe("posing", time.perf_counter() - t)
            for s in range(0, len(frames), chunk):
                part = frames[s : s + chunk]
                if refine is not None:
                    t = time.perf_counter()
                    part = self.refine_pool.refine(part, outfit.faces, body, p[s : s + chunk], tr[s : s + chunk],
                                                   refine, rest=outfit.vertices)
                    self._observe("refine", time.perf_counter() - t)
                yield part

    def export_animation(self, outfit: RiggedOutfit, poses: np.ndarray, translation: np.ndarray,
                         refine: RefineSettings | None = None, chunk: int = 32, body: Body | None = None,
                         progress: Callable[[int], None] | None = None,
                         ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]] | None]:
        """What an engine needs to replay `pose_chunks`: the pose keys (T, P) float32 (the morph-target
        weights) and, with `refine`, per frame what refinement moved, in the outfit's rest space (so a
        morph target before skinning reproduces it): (vertex indices (k,) int64, offsets (k, 3) float32 m).
        body: the outfit's body as the request resolved it (default: looked up by name, once). progress: called
        with the frames refined so far before each chunk (it may raise to stop the work)."""
        keys = np.concatenate([self.model.pose_keys(poses[s : s + POSE_BLOCK])
                               for s in range(0, len(poses), POSE_BLOCK)]) if len(poses) else np.zeros((0, 0))
        if refine is None:
            return keys.astype(np.float32), None
        body = body if body is not None else load_body(outfit.body)
        joints = body.joints
        corrections: list[tuple[np.ndarray, np.ndarray]] = []
        for start in range(0, len(poses), POSE_BLOCK):
            p, tr = poses[start : start + POSE_BLOCK], translation[start : start + POSE_BLOCK]
            frames = pose_outfit(outfit.vertices, outfit.rig, keys[start : start + POSE_BLOCK], joints, p, tr)
            rotations = forward_kinematics(p, joints, PARENTS, tr)[0][:, :, :3, :3]
            for s in range(0, len(frames), chunk):
                if progress is not None:
                    progress(len(corrections))
                part = frames[s : s + chunk]
                refined = self.refine_pool.refine(part, outfit.faces, body, p[s : s + chunk], tr[s : s + chunk],
                                                  refine, rest=outfit.vertices)
                for i, delta in enumerate(refined - part):
                    moved = np.flatnonzero(np.any(delta != 0, axis=1))
                    corrections.append((moved, rest_space_offsets(delta[moved], outfit.rig.weights[moved],
                                                                   rotations[s + i])))
        return keys.astype(np.float32), corrections

    def refine_chunks(self, vertices: np.ndarray, faces: np.ndarray, body: str | Body, poses: np.ndarray,
                      translation: np.ndarray, options: RefineSettings, chunk: int = 32,
                      inner: InnerStream | None = None, rest: np.ndarray | None = None) -> Iterator[np.ndarray]:
        """A given garment stream (T, N, 3), refined against the body in chunks: (n, N, 3) float32 each. With
        an inner layer, the post step between layers (drape.geometry.layers: the inner against the body, then the
        stream against the body, the refined inner, and both at once), frames split over the refinement workers
        (`RefinePool.refine_layers`); seams welded as in RefinePool. A body given by name is looked up once, when the
        first chunk is asked for: every chunk is refined against that Body, even if it is deleted meanwhile. rest: the
        garment's rest shape (N, 3) m, if given (not with inner): edges kept near their rest lengths, as animate's."""
        body = resolved_body(body)
        if inner is not None:
            yield from self._refine_layers(vertices, faces, body, poses, translation, options, chunk, inner)
            return
        for start in range(0, len(vertices), chunk):
            t = time.perf_counter()
            s = slice(start, start + chunk)
            yield self.refine_pool.refine(vertices[s], faces, body, poses[s], translation[s], options, rest=rest)
            self._observe("refine", time.perf_counter() - t)

    def _refine_layers(self, vertices: np.ndarray, faces: np.ndarray, body: Body, poses: np.ndarray,
                       translation: np.ndarray, options: RefineSettings, chunk: int,
                       inner: InnerStream) -> Iterator[np.ndarray]:
        def welded(frames: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            first, group = coincident_groups(np.ascontiguousarray(frames.transpose(1, 0, 2)).reshape(
                frames.shape[1], -1))
            return first, regroup_faces(f, group), group

        first, outer_faces, group = welded(np.asarray(vertices), faces)
        inner_first, inner_faces, _ = welded(inner.vertices, inner.faces)
        for start in range(0, len(vertices), chunk):
            t = time.perf_counter()
            s = slice(start, start + chunk)
            out = self.refine_pool.refine_layers(inner.vertices[s][:, inner_first], inner_faces, vertices[s][:, first],
                                                 outer_faces, inner.thickness, body, poses[s], translation[s],
                                                 options)[1]
            yield out[:, group]
            self._observe("refine", time.perf_counter() - t)

    def layer_chunks(self, combination: LayerCombination, thickness: float, poses: np.ndarray,
                     translation: np.ndarray, chunk: int = 32, refine: RefineSettings | None = None,
                     fps: float = 30.0) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Two layers along a motion (poses (T, 24, 3) rad, translation (T, 3) m, fps frames/s): (inner (n, Ni, 3),
        outer (n, No, 3)) float32 m in chunks of up to `chunk` frames. The inner layer is posed by its template's
        inner-layer network where one is served (`inner_chunks`), else by its own served DeePSD rig; the outer by
        the combination's outer-layer network where one is served (`outer_chunks`: the inner's thickness m), else
        by its DeePSD rig; with `refine`, the post step between layers (drape.geometry.layers, the thickness) over
        the refinement workers (`RefinePool.refine_layers`): the inner and the outer out of the body, the outer out
        of the inner, then of both at once."""
        inner_t, outer_t = combination.inner, combination.outer
        if outer_t.network is not None:
            outer_chunks = self.outer_chunks(combination, thickness, poses, translation, fps, chunk)
        else:
            outer_chunks = self.pose_chunks(self.rig(outer_t.vertices, outer_t.faces, outer_t.body), poses,
                                            translation, chunk)
        if inner_t.network is not None:
            inner_chunks = self.inner_chunks(inner_t, poses, translation, chunk)
        else:
            inner_chunks = self.pose_chunks(self.rig(inner_t.vertices, inner_t.faces, inner_t.body), poses,
                                            translation, chunk)
        start = 0
        for inner, outer in zip(inner_chunks, outer_chunks, strict=True):
            if refine is not None:
                t = time.perf_counter()
                at = slice(start, start + len(inner))
                inner, outer = self.refine_pool.refine_layers(inner, inner_t.faces, outer, outer_t.faces, thickness,
                                                              inner_t.body, poses[at], translation[at], refine)
                self._observe("refine", time.perf_counter() - t)
            start += len(inner)
            yield inner, outer

    def inner_chunks(self, template: LayerTemplate, poses: np.ndarray, translation: np.ndarray,
                     chunk: int = 32) -> Iterator[np.ndarray]:
        """An inner layer posed by its network (template.network: MGN's pose MLP -> basis coefficients, then the
        batched posing of a rig): (n, Ni, 3) float32 m in chunks of up to `chunk` frames."""
        network = template.network
        if not isinstance(network, InnerModel):
            raise ValueError(f"{template.name}: no inner-layer network is served")
        outfit = RiggedOutfit(template.name, template.body, template.vertices, template.faces, network.rig)
        return self.pose_chunks(outfit, poses, translation, chunk, pose_keys=network.pose_keys)

    def outer_chunks(self, combination: LayerCombination, thickness: float, poses: np.ndarray,
                     translation: np.ndarray, fps: float, chunk: int = 32) -> Iterator[np.ndarray]:
        """An outer layer posed by its network (combination.outer.network: MGN's Transformer over windows of the
        motion, reading the inner network's keys and the thickness m; then the batched posing of a rig):
        (n, No, 3) float32 m in chunks of up to `chunk` frames. The keys of the whole motion are computed first."""
        inner, outer = combination.inner.network, combination.outer.network
        if not isinstance(outer, OuterModel) or not isinstance(inner, InnerModel):
            raise ValueError(f"{combination.outer.name}: no outer-layer network is served")
        t = time.perf_counter()
        p = np.asarray(poses, np.float32).reshape(len(poses), 24, 3)
        keys = outer.pose_keys(p, translation, fps, thickness, inner.pose_keys(p),
                               load_body(combination.outer.body).joints)
        self._observe("pose", time.perf_counter() - t)
        done = 0

        def next_keys(block: np.ndarray) -> np.ndarray:  # pose_chunks asks for consecutive blocks
            nonlocal done
            done += len(block)
            return keys[done - len(block):done]

        t_ = combination.outer
        outfit = RiggedOutfit(t_.name, t_.body, t_.vertices, t_.faces, outer.rig)
        return self.pose_chunks(outfit, poses, translation, chunk, pose_keys=next_keys)

    def garment_chunks(self, garment: IntrinsicGarment, latents: np.ndarray, poses: np.ndarray,
                       translation: np.ndarray, chunk: int = 32, refine: RefineSettings | None = None,
                       residual: KeyframeResidual | None = None, fps: float | None = None) -> Iterator[np.ndarray]:
        """An intrinsic garment's stream: latents (T, Z), one per frame of the motion (poses (T, 24, 3) rad,
        translation (T, 3) m, at fps; None: the model's) -> world-space vertices (n, N, 3) float32 m in chunks of
        up to `chunk` frames,
        refined against the garment's body (its template faces) if asked, with the keyframes' `residual` added
        (character space) when given. Decoding runs DECODE_BLOCK
        frames per ONNX Runtime call, handed out a chunk at a time; the root frames are computed once."""
        motion = garment.motion_frames(poses, translation, fps)
        block = max(chunk, DECODE_BLOCK)
        start = 0
        for frames in garment.decode_chunks(latents, motion, block, observe=self._observe, residual=residual):
            for s in range(0, len(frames), chunk):
                part = frames[s : s + chunk]
                if refine is not None:
                    t = time.perf_counter()
                    at = slice(start + s, start + s + len(part))
                    part = self.refine_pool.refine(part, garment.faces, garment.body, poses[at], translation[at],
                                                   refine)
                    self._observe("refine", time.perf_counter() - t)
                yield part
            start += len(frames)

    def close(self) -> None:
        """Stop the refinement worker processes, if any started."""
        self.refine_pool.close()

    def warm_up(self) -> None:
        """One small rig and pose, so the first request does not pay ORT's start-up; the layer catalog built (its
        templates generated, its networks loaded: ~4 s the first GET /v1/garments or /v1/layers paid, over a
        client's 10 s timeout on a busy 2-core machine); the refinement workers started."""
        v = np.array([[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2], [0.1, 1.1, 0.25]], dtype=np.float32)
        f = np.array([[0, 1, 2], [1, 3, 2]], dtype=np.int32)
        rig = self.model.rig(v, f, load_body("neutral"))
        outfit = RiggedOutfit("warm-up", "neutral", v, f, rig)
        for _ in self.pose_chunks(outfit, np.zeros((2, 24, 3)), np.zeros((2, 3))):
            pass
        self.served_frames()
        self.garments.warm_up()
        self.layers.templates()
        if self.refine_pool.workers >= 2:
            self.refine_pool.start()
