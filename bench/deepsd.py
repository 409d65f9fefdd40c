"""DeePSD speed, measured in one run with ratios against the plain baselines.

1. Rig latency (outfit network) at N = 1k, 10k, 30k vertices: ONNX Runtime vs torch eager,
   same weights (a freshly initialised model: speed does not depend on training).
2. Posing 300 frames of a 10k-vertex outfit: the batched path (pose keys for all frames,
   one GEMM for the PSD offsets, batched LBS) vs a per-frame loop over the same functions.
3. The shipped model's rig at the same sizes, whose weights keep to each vertex's candidate joints when its
   manifest says so (drape.geometry.queries.candidate_joints, computed per request from the body): the
   candidate joints alone, and the whole rig against (1)'s rig without them (same architecture).
Every ONNX Runtime model here reads a mesh as it is (`densify_edge=None`, `ort_model`), as the torch side does:
the service reads a mesh with a mean edge over 25 mm subdivided (the 1k outfit as ~3.9k vertices), which would
time ORT's rig on another mesh than torch's (and than (3)'s candidate joints alone).
Run: .venv/bin/python -m bench.deepsd   (needs the [train] extra for the torch side)
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.export.deepsd import export_deepsd_from_checkpoints
from drape.geometry.queries import candidate_joints
from drape.models.deepsd import DeployedOutfitNet, OutfitNet, PoseNet
from drape.runtime.deepsd import MODEL_DIR, DeePSDModel, network_inputs, pose_outfit


def timed(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def ort_model(model_dir: str | Path = MODEL_DIR) -> DeePSDModel:
    """A DeePSD export on 2 threads, reading a mesh as it is (no subdivision), as `network_inputs` gives torch."""
    return DeePSDModel(model_dir, threads=2, densify_edge=None)


def main() -> None:
    torch.set_num_threads(2)
    with tempfile.TemporaryDirectory() as d:
        export_deepsd_from_checkpoints("unused", d, init=True)
        model = ort_model(d)
        torch.manual_seed(0)  # the same initial weights the export used
        net = DeployedOutfitNet(OutfitNet()).eval()
        PoseNet()
        print("rig latency (median of repeats)")
        print(f"{'N':>6s} {'ORT ms':>9s} {'torch ms':>9s} {'torch/ORT':>10s}")
        outfits = {}
        for n in (1000, 10000, 30000):
            o = generate_outfit("tshirt,trousers", vertices=n, seed=n)
            outfits[n] = o
            inputs = network_inputs(o.vertices, o.faces)
            tin = [torch.from_numpy(inputs[k]) for k in ("features", "nbr_idx", "nbr_w")]
            repeat = 10 if n <= 10000 else 4
            t_ort = timed(lambda: model.rig(o.vertices, o.faces), repeat)  # noqa: B023
            with torch.no_grad():
                t_torch = timed(lambda: (network_inputs(o.vertices, o.faces), net(*tin)), repeat)  # noqa: B023
            print(f"{len(o.vertices):6d} {t_ort * 1e3:9.1f} {t_torch * 1e3:9.1f} {t_torch / t_ort:10.2f}")

        body = load_body("neutral")
        o = outfits[10000]
        rig = model.rig(o.vertices, o.faces, body)
        clip = load_clip("walk")
        idx = np.arange(300) % clip.num_frames
        poses, trans = clip.poses[idx].astype(np.float64), clip.trans[idx].astype(np.float64)

        def batched():
            return pose_outfit(o.vertices, rig, model.pose_keys(poses), body.joints, poses, trans)

        def loop():
            return [pose_outfit(o.vertices, rig, model.pose_keys(poses[t : t + 1]), body.joints,
                                poses[t : t + 1], trans[t : t + 1]) for t in range(len(poses))]

        t_b = timed(batched, 3)
        t_l = timed(loop, 1)
        print(f"\nposing {len(poses)} frames x {len(o.vertices)} vertices")
        print(f"batched: {t_b:.3f} s ({len(poses) / t_b:.0f} frames/s); per-frame loop: {t_l:.3f} s "
              f"({len(poses) / t_l:.0f} frames/s); loop/batched = {t_l / t_b:.1f}x")

        shipped = ort_model()
        print(f"\nthe shipped model's rig ({shipped.manifest['version']}; candidate joints: "
              f"{shipped.joint_candidates})")
        print(f"{'N':>6s} {'candidates ms':>13s} {'rig ms':>9s} {'no-candidates rig ms':>20s} {'ratio':>6s}")
        for n, o in outfits.items():
            repeat = 10 if n <= 10000 else 4
            t_c = timed(lambda: candidate_joints(o.vertices, body.vertices, body.weights, parents=body.parents,  # noqa: B023
                                                 **(shipped.joint_candidates or {})), repeat)
            t_s = timed(lambda: shipped.rig(o.vertices, o.faces, body), repeat)  # noqa: B023
            t_p = timed(lambda: model.rig(o.vertices, o.faces), repeat)  # noqa: B023
            print(f"{len(o.vertices):6d} {t_c * 1e3:13.1f} {t_s * 1e3:9.1f} {t_p * 1e3:20.1f} {t_s / t_p:6.2f}")


if __name__ == "__main__":
    main()
