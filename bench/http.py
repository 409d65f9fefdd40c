"""Moving a posed vertex stream over HTTP on loopback, beside a raw socket moving the same bytes, in one run.

A ~10k-vertex outfit posed for 300 frames (36 MB of float32) is fetched from a real uvicorn server on
127.0.0.1 (drape's own server configuration), the request an npz of the motion's arrays (as the client
sends it; JSON for the JSON row): as npz (httpx, read into one preallocated array by `NpzReader` as it arrives), as the frame stream read
into one preallocated array (`Client.animate`), as the frame stream frame by frame
(`Client.animate_stream`, then stacked) and, for scale, as JSON. Each time
includes posing, encoding, transfer and decoding into one numpy array on the client. The baseline is a
plain TCP socket on loopback sending the same number of bytes into a preallocated buffer (no HTTP, no
posing): the ceiling for this machine. Prints MB/s (of float32 payload) and the ratio to the raw socket.
Run: .venv/bin/python -m bench.http [--repeat 5] [--frames 300] [--vertices 10000] [--no-json]
"""

from __future__ import annotations

import argparse
import socket
import statistics
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import httpx
import numpy as np
import uvicorn

import drape
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.schemas.binary import NPZ, NpzReader, encode_npz
from drape.service.app import create_app
from drape.service.server import server_config
from drape.service.settings import Settings


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--vertices", type=int, default=10000)
    p.add_argument("--no-json", action="store_true", help="skip the (slow) JSON row")
    args = p.parse_args()
    with loopback_server(Settings(max_json_values=40_000_000)) as url:
        measure(args, url)


@contextmanager
def loopback_server(settings: Settings | None = None) -> Iterator[str]:
    """The service (default settings unless given) on a free port of 127.0.0.1, in a thread, with drape's
    server configuration: yields its base URL. On exit the server shuts down (its lifespan too)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    settings = (settings or Settings()).model_copy(update={"host": "127.0.0.1", "port": port})
    server = uvicorn.Server(server_config(create_app(settings), settings, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=30)


def raw_socket_transfer(nbytes: int, piece: int = 1 << 20) -> float:
    """Seconds to send `nbytes` over a loopback TCP connection into a preallocated buffer (the ceiling)."""
    payload = memoryview(np.ones(piece, np.uint8))
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(1)

        def send() -> None:
            conn, _ = listener.accept()
            with conn:
                left = nbytes
                while left > 0:
                    left -= conn.send(payload[: min(piece, left)])

        sender = threading.Thread(target=send)
        sender.start()
        buf = bytearray(nbytes)
        view = memoryview(buf)
        t = time.perf_counter()
        with socket.create_connection(listener.getsockname()) as c:
            got = 0
            while got < nbytes:
                n = c.recv_into(view[got:])
                if n == 0:
                    break
                got += n
        seconds = time.perf_counter() - t
        sender.join()
    assert got == nbytes
    return seconds


def measure(args: argparse.Namespace, url: str) -> None:
    """Fetch the posed stream each way from the server at `url`, interleaved with the raw socket, then print."""
    outfit = generate_outfit("tshirt,trousers", vertices=args.vertices, seed=1)
    clip = load_clip("walk")
    idx = np.arange(args.frames) % clip.num_frames
    motion = {"poses": clip.poses[idx], "translation": clip.trans[idx], "fps": clip.fps}
    nbytes = args.frames * len(outfit.vertices) * 3 * 4
    with drape.Client(url, timeout=600) as client, httpx.Client(base_url=url, timeout=600) as http:
        oid = client.rig((outfit.vertices, outfit.faces)).outfit_id
        body = {"outfit_id": oid, "motion": {"poses": clip.poses[idx].tolist(),
                                             "translation": clip.trans[idx].tolist(), "fps": clip.fps}}

        def via_json() -> np.ndarray:
            r = http.post("/v1/outfits/animate", json=body, headers={"accept": "application/json"})
            r.raise_for_status()
            return np.asarray(r.json()["vertices"], dtype=np.float32)

        npz_request = encode_npz({"outfit_id": np.array(oid), "poses": clip.poses[idx], "translation": clip.trans[idx],
                                  "fps": np.array(clip.fps)})

        def via_npz() -> np.ndarray:  # the request as npz too, as the client sends it
            reader = NpzReader(("vertices",))
            with http.stream("POST", "/v1/outfits/animate", content=npz_request,
                             headers={"accept": NPZ, "content-type": NPZ}) as r:
                r.raise_for_status()
                for data in r.iter_raw():
                    reader.feed(data)
            assert reader.done
            return reader.arrays["vertices"]

        ways: dict[str, Callable[[], np.ndarray | None]] = {
            "raw socket": lambda: None,
            "npz": via_npz,
            "frame stream": lambda: client.animate(outfit_id=oid, motion=motion),
            "per frame": lambda: np.stack(list(client.animate_stream(outfit_id=oid, motion=motion))),
        }
        if not args.no_json:
            ways["json"] = via_json
        times: dict[str, list[float]] = {name: [] for name in ways}
        ref = None
        for _ in range(args.repeat):  # interleaved: each repeat measures every way once
            for name, fn in ways.items():
                if name == "raw socket":
                    times[name].append(raw_socket_transfer(nbytes))
                    continue
                t = time.perf_counter()
                out = fn()
                times[name].append(time.perf_counter() - t)
                assert out is not None and out.shape == (args.frames, len(outfit.vertices), 3)
                ref = out if ref is None else ref
                assert np.array_equal(out, ref), name
    mb = nbytes / 1e6
    raw = statistics.median(times["raw socket"])
    print(f"{args.frames} frames x {len(outfit.vertices)} vertices = {mb:.1f} MB float32, "
          f"median of {args.repeat} interleaved repeats")
    print(f"{'transport':14s} {'seconds':>8s} {'MB/s':>8s} {'frames/s':>9s} {'/ raw socket':>13s}")
    for name, ts in times.items():
        sec = statistics.median(ts)
        print(f"{name:14s} {sec:8.3f} {mb / sec:8.1f} {args.frames / sec:9.0f} {raw / sec:13.3f}")


if __name__ == "__main__":
    main()
