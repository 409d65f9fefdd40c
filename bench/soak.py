"""Soak and overload runs against a real `drape serve` process on loopback (bounded in time, loopback only).

soak (default): `--clients 3` threads send a mix of requests for `--minutes` (rig JSON and npz, animate
npz/stream/JSON, refine npz, catalogue GETs, bad inputs that must answer 4xx); prints per-kind latency
percentiles, the unexpected answers (anything but the kind's expected status), and the server's RSS
(serving process + its refinement workers) at 60 s and at the end.

overload (`--overload 48`): that many heavy requests (`--frames` x ~`--vertices` with refinement) at
once while /healthz is probed every 20 ms; prints the status codes (only 200 and the designed 503 are
expected), /healthz p50/p99/max, and the peak RSS.

Run: .venv/bin/python -m bench.soak --minutes 10            (the issue's 10-minute 3-client soak)
     .venv/bin/python -m bench.soak --overload 48           (48 concurrent heavy requests)
"""

from __future__ import annotations

import argparse
import io
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import httpx
import numpy as np

from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit

NPZ, FRAMES = "application/x-npz", "application/x-drape-frames"


def family_rss_mb(pid: int) -> float:
    """Resident memory of `pid` and every process under it, MB (from /proc)."""
    children: dict[int, list[int]] = defaultdict(list)
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                ppid = int(open(f"/proc/{entry}/stat").read().rsplit(")", 1)[1].split()[1])
            except OSError:
                continue
            children[ppid].append(int(entry))
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        todo += children.get(p, [])
        try:
            for line in open(f"/proc/{p}/status"):
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total / 1024


@contextmanager
def served(env: dict[str, str] | None = None) -> Iterator[tuple[str, subprocess.Popen]]:
    """`drape serve` in its own process on a free loopback port: yields (URL, process); SIGTERM at the end."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    full = {**os.environ, "DRAPE_HOST": "127.0.0.1", "DRAPE_PORT": str(port), **(env or {})}
    proc = subprocess.Popen([sys.executable, "-c", "from drape.cli import main; main()", "serve"], env=full,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.time() + 120
        while time.time() < deadline:
            try:
                if httpx.get(f"{url}/readyz").status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.3)
        yield url, proc
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(40)
        except subprocess.TimeoutExpired:
            proc.kill()


def npz_bytes(**arrays: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def request_kinds(vertices: int) -> dict[str, tuple[int, Callable[[httpx.Client], httpx.Response]]]:
    """kind -> (expected status, a function sending one such request)."""
    outfit = generate_outfit("tshirt", vertices=vertices, seed=5)
    v, f = outfit.vertices, outfit.faces
    mesh = {"vertices": v.round(5).tolist(), "faces": f.tolist()}
    walk = load_clip("walk")
    poses = walk.poses[:30].reshape(30, 72)
    rig_npz = npz_bytes(vertices=v, faces=f)

    def animate(c: httpx.Client, accept: str, refine: bool = False) -> httpx.Response:
        return c.post("/v1/outfits/animate", json={"outfit": mesh, "motion": {"clip": "walk"}, "refine": refine},
                      headers={"accept": accept})

    def stream(c: httpx.Client) -> httpx.Response:
        with c.stream("POST", "/v1/outfits/animate", json={"outfit": mesh, "motion": {"clip": "kick"}},
                      headers={"accept": FRAMES}) as r:
            r.read()
        return r

    def refine(c: httpx.Client) -> httpx.Response:
        frames = np.repeat(v[None], 30, axis=0)
        return c.post("/v1/refine", content=npz_bytes(vertices=frames, faces=f, poses=poses),
                      headers={"content-type": NPZ, "accept": NPZ})

    return {
        "rig json": (200, lambda c: c.post("/v1/outfits/rig", json=mesh)),
        "rig npz": (200, lambda c: c.post("/v1/outfits/rig", content=rig_npz,
                                          headers={"content-type": NPZ, "accept": NPZ})),
        "animate npz": (200, lambda c: animate(c, NPZ)),
        "animate json": (200, lambda c: animate(c, "application/json")),
        "animate refine": (200, lambda c: animate(c, NPZ, refine=True)),
        "stream": (200, stream),
        "refine npz": (200, refine),
        "catalogue": (200, lambda c: c.get("/v1/motions")),
        "bad json": (400, lambda c: c.post("/v1/outfits/rig", content=b"[" * 5000,
                                           headers={"content-type": "application/json"})),
        "bad mesh": (422, lambda c: c.post("/v1/outfits/rig", json={"vertices": [[0, 0, 0]] * 3,
                                                                     "faces": [[0, 1, 2]]})),
        "unknown id": (404, lambda c: c.post("/v1/outfits/animate", json={"outfit_id": "x",
                                                                          "motion": {"clip": "walk"}})),
    }


def soak(args: argparse.Namespace) -> None:
    kinds = request_kinds(args.vertices)
    lat: dict[str, list[float]] = defaultdict(list)
    unexpected: list[str] = []
    stop = time.time() + 60 * args.minutes
    rss: list[tuple[float, float]] = []
    with served() as (url, proc):
        t0 = time.time()

        def client(seed: int) -> None:
            rnd = random.Random(seed)
            names = list(kinds)
            with httpx.Client(base_url=url, timeout=120) as c:
                while time.time() < stop:
                    name = rnd.choice(names)
                    status, send = kinds[name]
                    t = time.perf_counter()
                    try:
                        r = send(c)
                        code = r.status_code
                    except httpx.HTTPError as exc:
                        code = -1
                        unexpected.append(f"{name}: {type(exc).__name__}")
                    lat[name].append(time.perf_counter() - t)
                    if code != status and code != -1:
                        unexpected.append(f"{name}: {code}")

        threads = [threading.Thread(target=client, args=(i,)) for i in range(args.clients)]
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            rss.append((time.time() - t0, family_rss_mb(proc.pid)))
            time.sleep(5)
        for t in threads:
            t.join()
    total = sum(len(v) for v in lat.values())
    print(f"soak: {args.clients} clients, {args.minutes:g} min, {total} requests, "
          f"{len(unexpected)} unexpected answers {sorted(set(unexpected))[:10]}")
    print(f"{'kind':16s} {'count':>6s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s}")
    for name, ts in sorted(lat.items()):
        q = np.percentile(np.array(ts) * 1000, [50, 99])
        print(f"{name:16s} {len(ts):6d} {q[0]:8.1f} {q[1]:8.1f} {max(ts) * 1000:8.1f}")
    after_warmup = [m for t, m in rss if t >= 60] or [rss[-1][1]]
    print(f"RSS (server + workers): {rss[0][1]:.0f} MB at start, {after_warmup[0]:.0f} MB at 60 s, "
          f"{rss[-1][1]:.0f} MB at the end, max {max(m for _, m in rss):.0f} MB; "
          f"growth after warm-up {100 * (rss[-1][1] / after_warmup[0] - 1):+.1f}%")


def overload(args: argparse.Namespace) -> None:
    outfit = generate_outfit("tshirt,trousers", vertices=args.vertices, seed=2)
    clip = load_clip("walk")
    idx = np.arange(args.frames) % clip.num_frames
    body = {"outfit": {"vertices": outfit.vertices.round(5).tolist(), "faces": outfit.faces.tolist()},
            "motion": {"poses": clip.poses[idx].reshape(-1, 72).tolist(), "translation": clip.trans[idx].tolist()},
            "refine": True}
    codes: list[int] = []
    health: list[float] = []
    peak = [0.0]
    with served() as (url, proc):
        base = family_rss_mb(proc.pid)
        done = threading.Event()

        def heavy() -> None:
            try:
                r = httpx.post(f"{url}/v1/outfits/animate", json=body, headers={"accept": NPZ}, timeout=600)
                codes.append(r.status_code)
            except httpx.HTTPError as exc:
                codes.append(-1)
                print("error:", type(exc).__name__, exc)

        def probe() -> None:
            with httpx.Client(base_url=url, timeout=10) as c:
                while not done.is_set():
                    t = time.perf_counter()
                    c.get("/healthz")
                    health.append(time.perf_counter() - t)
                    peak[0] = max(peak[0], family_rss_mb(proc.pid))
                    time.sleep(0.02)

        prober = threading.Thread(target=probe)
        prober.start()
        t0 = time.perf_counter()
        threads = [threading.Thread(target=heavy) for _ in range(args.overload)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        done.set()
        prober.join()
        wall = time.perf_counter() - t0
    h = np.array(health) * 1000
    counts = {c: codes.count(c) for c in sorted(set(codes))}
    print(f"overload: {args.overload} heavy requests ({args.frames} frames x {len(outfit.vertices)} vertices, "
          f"refined) at once: status {counts} in {wall:.1f} s")
    print(f"/healthz during it: {len(h)} probes, p50 {np.percentile(h, 50):.1f} ms, "
          f"p99 {np.percentile(h, 99):.1f} ms, max {h.max():.1f} ms")
    print(f"RSS (server + workers): {base:.0f} MB before, peak {peak[0]:.0f} MB")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--clients", type=int, default=3)
    p.add_argument("--overload", type=int, default=0, help="this many heavy requests at once instead of the soak")
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--vertices", type=int, default=2000)
    args = p.parse_args()
    overload(args) if args.overload else soak(args)


if __name__ == "__main__":
    main()
