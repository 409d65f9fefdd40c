"""`POST /v1/refine` over HTTP on loopback: the request as JSON vs as npz (what `drape.Client.refine` sends).

Input: the long sleeve + trousers outfit at about 6k vertices on the held-out clip dance_b (every
5th frame, 31 frames) posed by the nearest-body-weights LBS baseline, refined by a real uvicorn
server on 127.0.0.1 with its default settings (2 refinement workers). Each time is the whole round
trip: encoding the request, transfer, validation, posing the body, refinement, the npz answer and
decoding it into a numpy array. The two ways alternate; printed: the median seconds of `--repeat`,
ms per frame, and the ratio to JSON. Both give the same frames (checked).

Run: .venv/bin/python -m bench.refine_http [--repeat 3] (about 1 minute on the 2-core machine)
"""

from __future__ import annotations

import argparse
import io
import statistics
import time

import httpx
import numpy as np

from bench.http import loopback_server
from bench.refine import baseline_input, posed_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.schemas.binary import NPZ, decode_npz


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    body, p, t, _ = posed_body(np.arange(0, load_clip("dance_b").num_frames, 5))
    o = generate_outfit("longsleeve,trousers", vertices=6000, seed=77)
    g = baseline_input(o, body, p, t).astype(np.float32)
    motion = {"poses": p.tolist(), "translation": t.tolist(), "fps": 30.0}
    buf = io.BytesIO()
    np.savez(buf, vertices=g, faces=o.faces, poses=p, translation=t, fps=np.array(30.0))
    requests = {
        "json": {"json": {"vertices": g.tolist(), "faces": o.faces.tolist(), "motion": motion},
                 "headers": {"Accept": NPZ}},
        "npz": {"content": buf.getvalue(), "headers": {"Content-Type": NPZ, "Accept": NPZ}},
    }
    seconds: dict[str, list[float]] = {name: [] for name in requests}
    frames: dict[str, np.ndarray] = {}
    with loopback_server() as url, httpx.Client(base_url=url, timeout=600) as http:
        for k in range(args.repeat):
            for name in (list(requests) if k % 2 == 0 else list(reversed(requests))):
                t0 = time.perf_counter()
                r = http.post("/v1/refine", **requests[name])  # type: ignore[arg-type]
                r.raise_for_status()
                frames[name] = decode_npz(r.content)["vertices"]
                seconds[name].append(time.perf_counter() - t0)
    assert np.array_equal(frames["json"], frames["npz"])
    med = {name: statistics.median(s) for name, s in seconds.items()}
    print(f"{len(g)} frames x {g.shape[1]} vertices, median of {args.repeat}")
    print(f"{'request':8s} {'seconds':>8s} {'ms/frame':>9s} {'x JSON':>7s}")
    for name, sec in med.items():
        print(f"{name:8s} {sec:8.2f} {sec / len(g) * 1e3:9.1f} {med['json'] / sec:7.1f}")


if __name__ == "__main__":
    main()
