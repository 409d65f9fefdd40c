"""Moving a posed vertex stream over HTTP on loopback: JSON vs npz vs the frame stream, in one run.

A 10k-vertex outfit posed for 300 frames (36 MB of float32) is fetched three ways from a
real uvicorn server on 127.0.0.1; each time includes posing, encoding, transfer and decoding
into a numpy array on the client. Prints MB/s (of float32 payload), frames/s and the ratio to JSON.
Run: .venv/bin/python -m bench.http [--repeat 3]
"""

from __future__ import annotations

import argparse
import socket
import statistics
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import httpx
import numpy as np
import uvicorn

import drape
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.service.app import create_app
from drape.service.settings import Settings


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--vertices", type=int, default=10000)
    args = p.parse_args()
    with loopback_server() as url:
        measure(args, url)


@contextmanager
def loopback_server() -> Iterator[str]:
    """The service with its default settings on a free port of 127.0.0.1, in a thread: yields its base URL.
    On exit the server shuts down (its lifespan too: the refinement workers stop)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(create_app(Settings()), host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=30)


def measure(args: argparse.Namespace, url: str) -> None:
    """Fetch the posed stream three ways from the server at `url`, then print the table."""
    outfit = generate_outfit("tshirt,trousers", vertices=args.vertices, seed=1)
    clip = load_clip("walk")
    idx = np.arange(args.frames) % clip.num_frames
    motion = {"poses": clip.poses[idx], "translation": clip.trans[idx], "fps": clip.fps}
    with drape.Client(url, timeout=600) as client:
        oid = client.rig((outfit.vertices, outfit.faces)).outfit_id
        body = {"outfit_id": oid, "motion": {"poses": clip.poses[idx].tolist(),
                                             "translation": clip.trans[idx].tolist(), "fps": clip.fps}}

        def via_json() -> np.ndarray:
            r = httpx.post(f"{url}/v1/outfits/animate", json=body, timeout=600)
            return np.asarray(r.json()["vertices"], dtype=np.float32)

        def via_npz() -> np.ndarray:
            return client.animate(outfit_id=oid, motion=motion)

        def via_stream() -> np.ndarray:
            return np.stack(list(client.animate_stream(outfit_id=oid, motion=motion)))

        results = {}
        ref = None
        for name, fn in (("json", via_json), ("npz", via_npz), ("frame stream", via_stream)):
            times = []
            for _ in range(args.repeat):
                t = time.perf_counter()
                out = fn()
                times.append(time.perf_counter() - t)
            ref = out if ref is None else ref
            assert out.shape == (args.frames, len(outfit.vertices), 3) and np.array_equal(out, ref)
            results[name] = statistics.median(times)
    mb = args.frames * len(outfit.vertices) * 3 * 4 / 1e6
    print(f"{args.frames} frames x {len(outfit.vertices)} vertices = {mb:.1f} MB float32, median of {args.repeat}")
    print(f"{'transport':14s} {'seconds':>8s} {'MB/s':>8s} {'frames/s':>9s} {'x JSON':>7s}")
    for name, sec in results.items():
        print(f"{name:14s} {sec:8.2f} {mb / sec:8.1f} {args.frames / sec:9.0f} {results['json'] / sec:7.1f}")


if __name__ == "__main__":
    main()
