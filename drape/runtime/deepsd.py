"""The shipped DeePSD model on ONNX Runtime, and batched posing (numpy + ORT's sgemm; no torch).

rig:   outfit vertices (N, 3) m + faces (F, 3) -> weights (N, 24), blend_shapes (P, N, 3) m
pose:  weights, blend shapes, pose keys (T, P) and a motion -> vertices (T, N, 3) m,
       V = LBS(T + sum_p keys_p D_p, J, theta, W) for all frames at once.

Posing is two GEMMs and a few passes of elementwise work (`pose_outfit`): the pose-space offsets
keys (T, P) @ D (P, 3N), written straight into the output, then, a few frames at a time (a block
that stays in cache), the blended joint transforms as one GEMM, transforms (12 n, 24) @ W^T
(24, N) -> 12 rows of n*N (one row per entry of the 3x4 affine), applied to rest + offsets with
contiguous numpy passes (9 multiplies, 12 additions a vertex-frame; no (T, N, 3, 4) temporary).
The GEMMs run on ONNX Runtime (MLAS, AVX-512 where the CPU has it; numpy's when onnxruntime is
missing): on the 2-core dev machine (AMD EPYC) the PSD GEMM ran 1.6x faster than on numpy's
OpenBLAS, which the environment there pins to its AVX2 kernels (OPENBLAS_CORETYPE=Haswell; as
fast without that). 10k vertices x 300 frames pose at ~10k frames/s there, against 1.7k frames/s
at best for the einsum formulation kept in `drape.geometry.lbs` (bench/pose.py).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drape.geometry.body_scale import BodyScale, body_height, body_scale, torso_size
from drape.geometry.mesh import densify, neighbour_table, vertex_normals, weld
from drape.geometry.skeleton import PARENTS, as_pose_array, forward_kinematics
from drape.runtime.model_files import checked_files, cpu_session

if TYPE_CHECKING:
    from drape.assets.body import Body

MODEL_DIR = Path(__file__).resolve().parents[1] / "assets" / "models" / "deepsd"


# one-ring neighbours a vertex's graph convolution reads at most: cloth meshes have 6-12 (the generator's
# garments 6-9, the ArcSim tops of ../shared/data/external 11-12, after welding and densifying), so the network
# reads them whole; a fan or n-gon of hundreds made every row of the table that long (one 120-gon line in a
# 1k-vertex OBJ took a rig from 0.5 to 3.8 GB) and is read through an evenly spaced subset
MAX_NEIGHBOURS = 16


def network_inputs(vertices: np.ndarray, faces: np.ndarray) -> dict[str, np.ndarray]:
    """The outfit network's inputs: features (N, 6) float32 = rest position (m) + unit normal;
    nbr_idx (N, K) int64 and nbr_w (N, K) float32, the padded one-ring table (K <= MAX_NEIGHBOURS)."""
    v = np.asarray(vertices, dtype=np.float64)
    idx, w = neighbour_table(faces, len(v), MAX_NEIGHBOURS)
    return {
        "features": np.concatenate([v, vertex_normals(v, faces)], axis=1).astype(np.float32),
        "nbr_idx": idx,
        "nbr_w": w,
    }


@dataclass(frozen=True)
class Rig:
    """weights (N, 24) float32 summing to 1; blend_shapes (P, N, 3) float32 metres."""

    weights: np.ndarray
    blend_shapes: np.ndarray


Range = tuple[float, float]


@lru_cache(maxsize=8)
def trained_ranges(bodies: tuple[str, ...]) -> tuple[Range, tuple[Range, Range]] | None:
    """Of the body presets a model was trained on: (heights (lowest, tallest), torso ((width lo, hi), (depth lo,
    hi))) m (drape.geometry.body_scale); None when one of them is not a preset here."""
    from drape.assets.body import list_bodies, load_body

    if not set(bodies) <= set(list_bodies()):
        return None
    presets = [load_body(b) for b in bodies]
    heights = [body_height(b.vertices) for b in presets]
    widths, depths = zip(*(torso_size(b.vertices, b.joints) for b in presets), strict=True)
    return (min(heights), max(heights)), ((min(widths), max(widths)), (min(depths), max(depths)))


# a mesh whose mean edge is longer than this (m) is read subdivided: chosen on the validation split
# (bench/deepsd_coarse.py at 400 and 3,000 vertices; docs/deepsd_experiments.md)
DENSIFY_EDGE = 0.025
DENSIFY_MAX_VERTICES = 20_000  # the finest mesh a coarse outfit is read as (rig time grows with it: bench/deepsd.py)


class DeePSDModel:
    """The two ONNX files of a DeePSD export, checked against their manifest's sha256."""

    def __init__(self, model_dir: str | Path = MODEL_DIR, threads: int = 2, scale_bodies: str | None = "height",
                 densify_edge: float | None = DENSIFY_EDGE, densify_ring: bool = False):
        """scale_bodies: "height" reads a garment on a body taller or shorter than every body trained on as if
        the body were scaled into the trained range of heights (`drape.geometry.body_scale`); "torso" also
        brings its torso's width and depth into the trained range; None reads it as it is. densify_edge (m): a
        mesh whose mean edge is longer is read subdivided (`drape.geometry.mesh.densify`) toward it; None: as
        it is. densify_ring: a subdivided mesh's vertex answers the mean of its own answer and its finer
        one-ring's mean (better on validation, bench.deepsd_coarse "0.025r", but off: averaged weights reach
        joints beyond a vertex's 4 candidates, so the served 4-influence rig would no longer be the network's own)."""
        self.densify_edge, self.densify_ring = densify_edge, densify_ring
        model_dir = Path(model_dir)
        self.manifest = json.loads((model_dir / "manifest.json").read_text())
        blobs = checked_files(model_dir, self.manifest, ("outfit", "pose"))
        # the outfit network's memory grows with the garment (~16 KB a vertex): no arena keeps it after a rig
        self.sessions = {name: cpu_session(blob, threads, arena=name != "outfit") for name, blob in blobs.items()}
        self.num_keys = int(self.manifest["files"]["pose"]["outputs"][0]["shape"][-1])
        # a model trained with its weights restricted to candidate joints takes them as an input
        self.joint_candidates: dict | None = self.manifest.get("joint_candidates")
        if scale_bodies not in (None, "height", "torso"):
            raise ValueError(f"scale_bodies must be None, 'height' or 'torso', got {scale_bodies!r}")
        trained = self.manifest.get("training", {}).get("config", {}).get("bodies")
        ranges = trained_ranges(tuple(trained)) if trained and scale_bodies else None
        self.trained_heights = None if ranges is None else ranges[0]
        self.trained_torso = None if ranges is None or scale_bodies != "torso" else ranges[1]

    def body_scale(self, body: Body | None) -> BodyScale | None:
        """How the network reads a garment on `body` (None: as it is)."""
        if body is None or self.trained_heights is None:
            return None
        scale = body_scale(body.vertices, body.joints, self.trained_heights, self.trained_torso)
        return None if scale.identity else scale

    def _inputs(self, vertices: np.ndarray, faces: np.ndarray, body: Body | None,
                scale: BodyScale | None) -> dict[str, np.ndarray]:
        """The outfit network's inputs for vertices (N, 3) already in its frame (scaled by `scale`)."""
        inputs = network_inputs(vertices, faces)
        if self.joint_candidates is not None:
            if body is None:
                raise ValueError("this DeePSD model restricts weights to the body's joints near each vertex: "
                                 "rig(...) needs the body")
            from drape.geometry.queries import candidate_joints

            body_vertices = body.vertices if scale is None else scale.apply(body.vertices)
            mask = candidate_joints(vertices, body_vertices, body.weights, parents=body.parents, **self.joint_candidates)
            inputs["joint_mask"] = mask.astype(np.float32)
        return inputs

    def _run(self, outputs: list[str], vertices: np.ndarray, faces: np.ndarray, body: Body | None) -> list[np.ndarray]:
        """The outfit network's `outputs` for the mesh, per input vertex (the vertex axis last but one), blend
        shapes in metres on `body`. The network reads garment and body scaled into its trained heights
        (`body_scale`); coincident vertices (UV seams) welded, so that seams cannot open; a mesh whose mean edge
        is longer than `densify_edge` there subdivided (its own vertices are the first of the finer mesh)."""
        welded, welded_faces, group = weld(vertices, faces)
        scale = self.body_scale(body)
        v, f = (welded if scale is None else scale.apply(welded)), welded_faces
        if self.densify_edge is not None:
            v, f = densify(v, f, self.densify_edge, DENSIFY_MAX_VERTICES)
        answers = self.sessions["outfit"].run(outputs, self._inputs(v, f, body, scale))
        if self.densify_ring and len(v) > len(welded):
            idx, w = neighbour_table(f, len(v), MAX_NEIGHBOURS)
            idx, w = idx[: len(welded)], w[: len(welded)]
            answers = [0.5 * (a[..., : len(welded), :] + np.einsum("nk,...nkc->...nc", w, a[..., idx, :]))
                       for a in answers]
        answers = [a[..., : len(welded), :][..., group, :] for a in answers]
        return [a if scale is None or name == "weights" else scale.unscale(a)
                for name, a in zip(outputs, answers, strict=True)]

    def rig(self, vertices: np.ndarray, faces: np.ndarray, body: Body | None = None) -> Rig:
        """Blend weights and pose-space blend shapes of an outfit in rest pose on `body` (needed by a model with
        `joint_candidates`; the others ignore it), as `_run` reads it."""
        w, d = self._run(["weights", "blend_shapes"], vertices, faces, body)
        return Rig(weights=w, blend_shapes=d)

    def blend_shapes_data(self, vertices: np.ndarray, faces: np.ndarray, body: Body | None = None) -> np.ndarray:
        """D_data alone (P, N, 3): the model without its physics branch Chi (for evaluation); as `rig` reads it."""
        return self._run(["blend_shapes_data"], vertices, faces, body)[0]

    def pose_keys(self, poses: np.ndarray) -> np.ndarray:
        """(T, 24, 3) or (T, 72) axis-angle -> (T, P) pose keys."""
        p = as_pose_array(poses).reshape(-1, 72).astype(np.float32)
        return self.sessions["pose"].run(["pose_keys"], {"poses": p})[0]


# bytes of the per-block blended transforms (12 floats a vertex-frame), so that a block stays in
# cache: 4-8 MiB were fastest at 10k vertices (0.5 MiB: 1.7x slower, 2 MiB: 1.1x)
BLOCK_BYTES = 4 * 2**20
# ONNX Runtime threads of the posing GEMMs (the engine's default `ort_threads`)
GEMM_THREADS = 2

Gemm = Callable[[np.ndarray, np.ndarray, np.ndarray], None]


def pose_outfit(
    rest_vertices: np.ndarray,
    rig: Rig,
    keys: np.ndarray,
    rest_joints: np.ndarray,
    poses: np.ndarray,
    translation: np.ndarray | None = None,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Pose an outfit for every frame at once -> (T, N, 3) float32 metres.

    rest_vertices (N, 3) m; keys (T, P) from `DeePSDModel.pose_keys`; rest_joints (24, 3) m
    of the body the outfit was rigged on; poses (T, 24, 3) or (T, 72) axis-angle radians;
    translation (T, 3) m or None; out: an optional C-contiguous (T, N, 3) float32 array to
    write into (and return). Equals `linear_blend_skinning(rest + keys @ D, W, FK(poses))`
    to float32 rounding (~1e-6 m).
    """
    return _pose(rest_vertices, rig, keys, rest_joints, poses, translation, out, _gemm_backend())


def _pose(
    rest_vertices: np.ndarray,
    rig: Rig,
    keys: np.ndarray,
    rest_joints: np.ndarray,
    poses: np.ndarray,
    translation: np.ndarray | None,
    out: np.ndarray | None,
    gemm: tuple[Gemm, Gemm],
) -> np.ndarray:
    """`pose_outfit` with its GEMMs given: (c = a @ b, c = a @ b.T), each writing into c."""
    matmul, matmul_t = gemm
    P, N, _ = rig.blend_shapes.shape
    keys = np.ascontiguousarray(keys, dtype=np.float32)
    T = len(keys)
    if out is None:
        out = np.empty((T, N, 3), dtype=np.float32)
    elif out.shape != (T, N, 3) or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous ({T}, {N}, 3) float32 array")
    if T == 0 or N == 0:
        return out
    transforms, _ = forward_kinematics(as_pose_array(poses), rest_joints, PARENTS, translation)
    if len(transforms) != T:
        raise ValueError(f"{len(transforms)} poses for {T} frames of pose keys")
    # the 3x4 affine parts as (12, T, 24): row 4 j + c of frame t, joint k = transforms[t, k, j, c]
    affine = transforms[:, :, :3, :].reshape(T, -1, 12).transpose(2, 0, 1).astype(np.float32)
    weights = np.ascontiguousarray(rig.weights, dtype=np.float32)  # (N, 24)
    rest = np.ascontiguousarray(np.asarray(rest_vertices, dtype=np.float32).T)  # (3, N)
    # the offsets of every frame straight into the output: (T, P) @ (P, 3N), one GEMM (faster than
    # GEMMs per cache-sized span of frames at 1k-30k vertices: each would stream D again)
    blend = np.ascontiguousarray(rig.blend_shapes, dtype=np.float32).reshape(P, 3 * N)
    matmul(keys, blend, out.reshape(T, 3 * N))
    step = max(1, min(T, BLOCK_BYTES // (48 * N)))
    scratch = _take_scratch(15 * step * N)
    try:
        _apply_blocks(out, affine, weights, rest, step, scratch, matmul_t)
    finally:
        _give_scratch(scratch)
    return out


def _apply_blocks(out: np.ndarray, affine: np.ndarray, weights: np.ndarray, rest: np.ndarray,
                  step: int, scratch: np.ndarray, matmul_t: Gemm) -> None:
    """out (T, N, 3) holds the offsets; make it rest (3, N) + offsets, skinned by the blended
    affine transforms (12, T, 24) and weights (N, 24), `step` frames at a time."""
    T, N, _ = out.shape
    m_buf, r_buf = scratch[: 12 * step * N], scratch[12 * step * N : 15 * step * N]
    for t0 in range(0, T, step):
        n = min(step, T - t0)
        k = n * N
        # blended transforms of n frames: (12 n, 24) @ W^T (24, N) -> m[4 j + c] = (n * N,) entries
        m = m_buf[: 12 * k].reshape(12, k)
        matmul_t(np.ascontiguousarray(affine[:, t0 : t0 + n]).reshape(12 * n, -1), weights,
                 m.reshape(12 * n, N))
        block = out[t0 : t0 + n]  # (n, N, 3): the offsets, overwritten by the posed vertices
        r = r_buf[: 3 * k].reshape(3, n, N)
        for c in range(3):  # rest + offsets, one coordinate per row
            np.add(block[:, :, c], rest[c], out=r[c])
        r2 = r.reshape(3, k)
        flat = block.reshape(k, 3)
        for j in range(3):  # posed_j = sum_c M[j, c] r_c + M[j, 3]
            m0, m1, m2, m3 = m[4 * j : 4 * j + 4]
            np.multiply(m0, r2[0], out=m0)
            np.multiply(m1, r2[1], out=m1)
            np.add(m0, m1, out=m0)
            np.multiply(m2, r2[2], out=m2)
            np.add(m0, m2, out=m0)
            np.add(m0, m3, out=flat[:, j])


# scratch arrays of finished calls (~5 MB each), kept for the next ones: a fresh multi-MB array is
# fresh pages, and faulting them in cost ~1 ms a call (a fifth of a 32-frame call at 10k vertices)
_SCRATCH: list[np.ndarray] = []
_SCRATCH_LOCK = threading.Lock()
_SCRATCH_KEPT = 4


def _take_scratch(size: int) -> np.ndarray:
    """A float32 array of `size` elements (1-D), from the kept ones when one is large enough."""
    with _SCRATCH_LOCK:
        for i, a in enumerate(_SCRATCH):
            if a.size >= size:
                return _SCRATCH.pop(i)[:size]
    return np.empty(size, dtype=np.float32)


def _give_scratch(a: np.ndarray) -> None:
    """Keep a scratch array (its whole base) for later calls; the smallest goes beyond
    `_SCRATCH_KEPT`."""
    base = a.base if isinstance(a.base, np.ndarray) else a
    with _SCRATCH_LOCK:
        _SCRATCH.append(base)
        _SCRATCH.sort(key=lambda x: x.size)
        if len(_SCRATCH) > _SCRATCH_KEPT:
            _SCRATCH.pop(0)


def _gemm_backend() -> tuple[Gemm, Gemm]:
    """The posing GEMMs on ONNX Runtime when it is installed, else numpy's."""
    sessions = _gemm_sessions()
    if sessions is None:
        return _numpy_gemm
    plain, transposed = sessions
    return (lambda a, b, c: _run_gemm(plain, a, b, c),
            lambda a, b, c: _run_gemm(transposed, a, b, c))


def _numpy_matmul(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
    np.matmul(a, b, out=c)


def _numpy_matmul_t(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
    np.matmul(a, b.T, out=c)


_numpy_gemm: tuple[Gemm, Gemm] = (_numpy_matmul, _numpy_matmul_t)


def _run_gemm(session: Any, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
    """c = a @ b (or a @ b.T) on an ONNX Runtime session; a, b, c C-contiguous float32, c
    written in place."""
    from onnxruntime import OrtValue

    binding = session.io_binding()
    binding.bind_ortvalue_input("a", OrtValue.ortvalue_from_numpy(a))
    binding.bind_ortvalue_input("b", OrtValue.ortvalue_from_numpy(b))
    binding.bind_ortvalue_output("c", OrtValue.ortvalue_from_numpy(c))
    session.run_with_iobinding(binding)


@lru_cache(maxsize=1)
def _gemm_sessions() -> tuple[Any, Any] | None:
    """Two one-node ONNX Runtime sessions, c = Gemm(a, b) and c = Gemm(a, b, transB=1), or None
    without onnxruntime."""
    try:
        import onnxruntime as ort
    except ImportError:
        return None
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = GEMM_THREADS
    opts.inter_op_num_threads = 1
    # idle workers sleep rather than spin between the short GEMMs, leaving the other core to the
    # numpy passes in between and to the refinement workers: posing ran as fast either way on the
    # 2-core machine, and faster without spinning while other processes used it (a square
    # 2048^3 product, by contrast, gets about one core's rate without spinning)
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return tuple(  # type: ignore[return-value]
        ort.InferenceSession(gemm_model(trans_b), opts, providers=["CPUExecutionProvider"])
        for trans_b in (False, True)
    )


def gemm_model(trans_b: bool) -> bytes:
    """A serialized ONNX model (IR 8, opset 17) of one float32 Gemm node: inputs a (M, K) and
    b (K, L), or (L, K) with trans_b; output c (M, L). Written out by hand in protobuf's wire
    format, since the serving install has onnxruntime but not the onnx package."""

    def varint(v: int) -> bytes:
        b = bytearray()
        while True:
            b.append((v & 0x7F) | (0x80 if v > 0x7F else 0))
            v >>= 7
            if not v:
                return bytes(b)

    def num(field: int, v: int) -> bytes:
        return varint(field << 3) + varint(v)

    def msg(field: int, payload: bytes | str) -> bytes:
        data = payload.encode() if isinstance(payload, str) else payload
        return varint(field << 3 | 2) + varint(len(data)) + data

    def tensor(name: str, dims: tuple[str, str]) -> bytes:  # ValueInfoProto, float32, named dims
        shape = b"".join(msg(1, msg(2, d)) for d in dims)
        return msg(1, name) + msg(2, msg(1, num(1, 1) + msg(2, shape)))

    node = msg(1, "a") + msg(1, "b") + msg(2, "c") + msg(4, "Gemm")
    if trans_b:
        node += msg(5, msg(1, "transB") + num(3, 1) + num(20, 2))  # AttributeProto INT
    graph = (msg(1, node) + msg(2, "gemm") + msg(11, tensor("a", ("M", "K")))
             + msg(11, tensor("b", ("L", "K") if trans_b else ("K", "L")))
             + msg(12, tensor("c", ("M", "L"))))
    return num(1, 8) + msg(2, "drape") + msg(7, graph) + msg(8, num(2, 17))
