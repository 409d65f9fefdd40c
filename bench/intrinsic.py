"""What the intrinsic garment space costs to serve: encode and decode of a whole motion, batched, with ONNX
Runtime (what the service runs) against torch eager on the same architecture in the same run (both timed
from poses to world-space vertices: root frames, motion windows, the networks, character to world space),
and the refinement post step per frame.

The torch model is built from the shipped manifest's model_config with fresh weights: the cost of a
forward pass does not depend on the weight values, so this times the same computation (torch is a dev
dependency; the service never imports it). The motion is procedural (seeded), `--frames` long.
Run: .venv/bin/python -m bench.intrinsic [--template skirt] [--frames 300] [--repeat 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drape.assets.procedural import generate_motion
from drape.geometry.character_space import (
    character_space_numpy,
    motion_windows,
    root_frames,
    world_space_numpy,
)
from drape.runtime.intrinsic import INTRINSIC_DIR, IntrinsicGarment


def _best(fn, repeat: int) -> float:  # noqa: ANN001
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--template", default="skirt")
    p.add_argument("--model", help="default drape/assets/models/intrinsic/<template>")
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--refine-frames", type=int, default=30)
    args = p.parse_args()
    import torch

    from drape.models.intrinsic import IntrinsicConfig, IntrinsicSpace

    g = IntrinsicGarment(args.model or INTRINSIC_DIR / args.template, threads=args.threads)
    torch.set_num_threads(args.threads)
    m = generate_motion(args.frames, seed=7, fps=g.fps)
    poses, trans = m.poses.astype(np.float64), m.trans.astype(np.float64)
    z = np.repeat(g.latent_mean[None].astype(np.float32), args.frames, axis=0)
    decoded = g.decode(z, poses, trans)
    ort_decode = _best(lambda: g.decode(z, poses, trans), args.repeat)
    ort_encode = _best(lambda: g.encode_frames(decoded, poses, trans), args.repeat)

    cfg = IntrinsicConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in g.manifest["model_config"].items()})
    model = IntrinsicSpace(cfg, torch.as_tensor(g.vertices)).eval()

    def torch_decode() -> None:  # the runtime's whole path: root frames, windows, decode, back to world space
        joints, rp, rr = root_frames(poses, trans, g.rest_joints, g.parents)
        w = torch.as_tensor(motion_windows(joints, rp, rr, cfg.window))
        with torch.no_grad():
            local = model.decode(torch.as_tensor(z), w).numpy()
        world_space_numpy(local, rp.astype(np.float32), rr.astype(np.float32))

    def torch_encode() -> None:
        joints, rp, rr = root_frames(poses, trans, g.rest_joints, g.parents)
        w = torch.as_tensor(motion_windows(joints, rp, rr, cfg.window))
        v = torch.as_tensor(character_space_numpy(decoded.astype(np.float64), rp, rr).astype(np.float32))
        with torch.no_grad():
            model.encode(v, w)

    torch_dec, torch_enc = _best(torch_decode, args.repeat), _best(torch_encode, args.repeat)

    from drape.runtime.engine import RefineSettings, body_surface, posed_body, refine_against

    n = min(args.refine_frames, args.frames)
    refiner = RefineSettings().refiner(g.faces, g.num_vertices)
    bodies = posed_body(g.body, poses[:n], trans[:n])
    t = time.perf_counter()
    refine_against(decoded[:n], body_surface(g.body), bodies, refiner)
    refine = (time.perf_counter() - t) / n

    T = args.frames
    print(f"{g.name}: {g.num_vertices} vertices, window {g.window}, {T} frames, {args.threads} threads, "
          f"median of {args.repeat}")
    print(f"{'':8s} {'ORT ms':>8s} {'ms/frame':>9s} {'torch ms':>9s} {'ms/frame':>9s} {'torch/ORT':>9s}")
    for name, o, tt in (("decode", ort_decode, torch_dec), ("encode", ort_encode, torch_enc)):
        print(f"{name:8s} {o * 1e3:8.1f} {o * 1e3 / T:9.3f} {tt * 1e3:9.1f} {tt * 1e3 / T:9.3f} {tt / o:9.2f}")
    print(f"refinement: {refine * 1e3:.1f} ms per frame (mean of {n} frames, one process)")


if __name__ == "__main__":
    main()
