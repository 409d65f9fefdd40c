"""Posing throughput against the old formulation, the PSD GEMM alone and a measured sgemm roofline.

For N = 1k, 10k, 30k vertices (generated tshirt+trousers outfits rigged by the shipped DeePSD
model) x 300 frames of the walk clip (pose keys from the shipped pose network, computed once,
outside the timings), prints the median frames/s over --repeat rounds (the methods take turns
within a round, so that load from other processes falls on all of them alike, 0.2 s apart) of:

  new        `pose_outfit`, returning a fresh (T, N, 3) array (what the engine does)
  new,out=   `pose_outfit` writing into a preallocated array (no page faults on a new 36 MB+)
  new/c      `pose_outfit` called on c-frame slices, outputs kept (the stream's chunks are
             settings.stream_chunk_frames = 32; the engine poses POSE_BLOCK = 128 frames a call)
  old        the previous formulation: offsets keys @ D (numpy), `forward_kinematics`,
             `linear_blend_skinning` (einsums), as `pose_outfit` was before issue 24
  old best   its fastest round: its (T, N, 12) float32 temporaries (144 MB at 10k) are fresh
             pages each call, and the kernel's time zeroing (and compacting) them for it swings
             from round to round (150-650 ms at 10k on the dev machine, mostly system time)
  psd ort    the PSD GEMM alone, keys (T, 128) @ D (128, 3N) on ONNX Runtime (MLAS, as posing does)
  psd np     the same GEMM with numpy (OpenBLAS)
  roofline   the flops of posing (2 P 3N + 2 * 12 * 24 N + 21 N a frame) / the best sgemm rate
             measured in this run (a 2048^3 float32 product on numpy and on ORT with 2 spinning
             threads, median)

and the ratios new/old, new/roofline, plus the largest |new - old| over all frames (metres).
OPENBLAS_CORETYPE / OPENBLAS_L2_SIZE are printed as found: numpy's OpenBLAS picks its kernels by
them (OPENBLAS_CORETYPE=Haswell keeps it on AVX2 on an AVX-512 machine), ORT's MLAS does not.
Run: .venv/bin/python -m bench.pose [--repeat 7] [--chunks 32] [--vertices 1000,10000,30000]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.lbs import linear_blend_skinning
from drape.geometry.skeleton import PARENTS, as_pose_array, forward_kinematics
from drape.runtime.deepsd import (
    GEMM_THREADS,
    DeePSDModel,
    Rig,
    _gemm_sessions,
    _run_gemm,
    gemm_model,
    pose_outfit,
)


def old_pose_outfit(rest: np.ndarray, rig: Rig, keys: np.ndarray, joints: np.ndarray,
                    poses: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """`pose_outfit` before issue 24: (T, N, 3) float32 m."""
    p, n, _ = rig.blend_shapes.shape
    offsets = np.asarray(keys, dtype=np.float32) @ rig.blend_shapes.reshape(p, n * 3)
    transforms, _ = forward_kinematics(as_pose_array(poses), joints, PARENTS, trans)
    rest_t = np.asarray(rest, dtype=np.float32)[None] + offsets.reshape(len(keys), n, 3)
    return linear_blend_skinning(rest_t, rig.weights, transforms)


def rounds(fns: dict[str, Callable[[], object]], repeat: int,
           settle: float = 0.2) -> dict[str, list[float]]:
    """Seconds of each function in each of `repeat` rounds, one call of each per round (after a
    warm-up), each call `settle` s after the previous one: numpy's OpenBLAS threads busy-wait ~0.1 s
    after a product and would otherwise slow down whatever runs next on the 2 cores."""
    times: dict[str, list[float]] = {k: [] for k in fns}
    for f in fns.values():
        f()
    for _ in range(repeat):
        for k, f in fns.items():
            time.sleep(settle)
            t = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t)
    return times


def ort_matmul(a: np.ndarray, b: np.ndarray, session: object | None = None) -> np.ndarray:
    """a @ b on ORT: on posing's own session (2 threads, no spinning) unless one is given."""
    sessions = _gemm_sessions()
    assert sessions is not None, "onnxruntime is needed"
    c = np.empty((a.shape[0], b.shape[1]), dtype=np.float32)
    _run_gemm(session or sessions[0], a, b, c)
    return c


def spinning_session() -> object:
    """ORT's Gemm with 2 spinning threads: ORT's best on a large square product (posing's
    sessions do not spin, which leaves a 2048^3 product on about one core's rate)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = GEMM_THREADS
    return ort.InferenceSession(gemm_model(False), opts, providers=["CPUExecutionProvider"])


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--chunks", default="32", help="comma-separated frame counts per call for new/c")
    p.add_argument("--vertices", default="1000,10000,30000")
    args = p.parse_args()
    chunks = [int(c) for c in args.chunks.split(",") if c]
    env = {k: os.environ.get(k, "unset") for k in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE")}
    print(f"{os.cpu_count()} CPUs; " + ", ".join(f"{k}={v}" for k, v in env.items()))

    a = np.random.default_rng(0).standard_normal((2048, 2048)).astype(np.float32)
    spin = spinning_session()
    sg = rounds({"numpy": lambda: a @ a, "ort": lambda: ort_matmul(a, a, spin)}, args.repeat)
    rate = {k: 2 * 2048**3 / statistics.median(t) / 1e9 for k, t in sg.items()}
    peak = max(rate.values())
    print(f"sgemm 2048^3 GFLOP/s (median): numpy {rate['numpy']:.0f}, ORT {rate['ort']:.0f}; "
          f"roofline uses {peak:.0f}")

    model = DeePSDModel()
    body = load_body("neutral")
    clip = load_clip("walk")
    idx = np.arange(args.frames) % clip.num_frames
    poses, trans = clip.poses[idx].astype(np.float64), clip.trans[idx].astype(np.float64)
    keys = model.pose_keys(poses)
    cols = (["new", "new,out="] + [f"new/{c}" for c in chunks]
            + ["old", "old best", "psd ort", "psd np", "roofline"])
    print(f"\nframes/s (median of {args.repeat}), {args.frames} frames, {keys.shape[1]} pose keys")
    print(f"{'N':>6s} " + " ".join(f"{c:>9s}" for c in cols)
          + f" {'new/old':>8s} {'new/roof':>9s} {'max|new-old| m':>15s}")
    for n in (int(v) for v in args.vertices.split(",")):
        fps, diff = measure(model, n, keys, body.joints, poses, trans, chunks, args.repeat)
        fps["roofline"] = peak * 1e9 / posing_flops(fps["vertices"], keys.shape[1])
        print(f"{fps['vertices']:6.0f} " + " ".join(f"{fps[c]:9.0f}" for c in cols)
              + f" {fps['new'] / fps['old']:8.2f} {fps['new'] / fps['roofline']:9.2f} {diff:15.2e}")


def posing_flops(n: float, p: int) -> float:
    """Flops of posing one frame of n vertices with p pose keys: the PSD GEMM, the blended 3x4
    transforms (a GEMM over 24 joints) and applying them (9 multiplies, 12 additions a vertex)."""
    return 2 * p * 3 * n + 2 * 12 * 24 * n + 21 * n


def measure(model: DeePSDModel, n: int, keys: np.ndarray, joints: np.ndarray, poses: np.ndarray,
            trans: np.ndarray, chunks: list[int], repeat: int) -> tuple[dict[str, float], float]:
    """frames/s of each method on an outfit of ~n vertices (and its vertex count under "vertices"),
    and max |new - old| in metres."""
    o = generate_outfit("tshirt,trousers", vertices=n, seed=1)
    rig = model.rig(o.vertices, o.faces, load_body("neutral"))
    v, t = o.vertices, len(keys)
    blend = rig.blend_shapes.reshape(len(rig.blend_shapes), -1)
    out = np.empty((t, len(v), 3), dtype=np.float32)
    diff = float(np.abs(pose_outfit(v, rig, keys, joints, poses, trans)
                        - old_pose_outfit(v, rig, keys, joints, poses, trans)).max())

    def chunked(c: int) -> Callable[[], object]:
        return lambda: [pose_outfit(v, rig, keys[s : s + c], joints, poses[s : s + c],
                                    trans[s : s + c]) for s in range(0, t, c)]

    fns: dict[str, Callable[[], object]] = {
        "new": lambda: pose_outfit(v, rig, keys, joints, poses, trans),
        "new,out=": lambda: pose_outfit(v, rig, keys, joints, poses, trans, out=out),
        **{f"new/{c}": chunked(c) for c in chunks},
        "psd ort": lambda: ort_matmul(keys, blend),
        "psd np": lambda: keys @ blend,
        "old": lambda: old_pose_outfit(v, rig, keys, joints, poses, trans),
    }
    times = rounds(fns, repeat)
    fps = {k: t / statistics.median(s) for k, s in times.items()}
    fps["old best"] = t / min(times["old"])
    fps["vertices"] = len(v)
    return fps, diff

if __name__ == "__main__":
    main()
