"""The probe's hostile inputs against a real `drape serve` process: each answers its 4xx (or a 200 that
reads only what it needs) within 2 s, the server's RSS (with its workers) stays within 20% of before,
and /healthz keeps answering meanwhile."""

import io
import socket
import threading
import time
import zipfile

import httpx
import numpy as np
import pytest
from test_uploads import TRI_BIN, glb, npy_bytes, png_header, tri_tree

from bench.soak import family_rss_mb, served

pytestmark = pytest.mark.serial  # its latency bars need the machine to itself

MB = 2**20


def npz_with_bomb(bomb_name: str) -> bytes:
    """A valid rig request (vertices, faces) beside a deflated member that inflates to 320 MB (over the
    default DRAPE_MAX_DECODED_BYTES of 256 MiB)."""
    buf = io.BytesIO()
    v = np.array([[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2], [0.1, 1.1, 0.25]], np.float32)
    arrays = {"vertices": v, "faces": np.array([[0, 1, 2], [1, 3, 2]], np.int32)}
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for k, a in arrays.items():
            if k != bomb_name:
                with zf.open(k + ".npy", "w") as f:
                    np.lib.format.write_array(f, a)
        with zf.open(bomb_name + ".npy", "w") as f:
            f.write(npy_bytes((80 * MB,)))
            for _ in range(40):
                f.write(bytes(8 * MB))
    return buf.getvalue()


def textured_glb() -> bytes:
    png = png_header(16000, 11000)
    tree = tri_tree()
    tree["bufferViews"].append({"buffer": 0, "byteOffset": 48, "byteLength": len(png)})
    tree["buffers"] = [{"byteLength": 48 + len(png)}]
    tree["meshes"][0]["primitives"][0]["material"] = 0
    tree["images"] = [{"bufferView": 2, "mimeType": "image/png"}]
    tree["textures"] = [{"source": 0}]
    tree["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    return glb(tree, TRI_BIN + png)


def cases() -> list[tuple[str, int, dict]]:
    """(name, expected status, httpx.post keyword arguments after the path) for each hostile input."""
    poses = np.zeros((10_000, 72)).tolist()
    return [
        ("glb declaring 1.2e9 indices", 400, {"url": "/v1/outfits/rig",
                                              "files": {"mesh": ("a.glb", glb(tri_tree(index_count=1_200_000_000)))}}),
        ("glb declaring 2e8 vertices", 400, {"url": "/v1/outfits/rig",
                                             "files": {"mesh": ("a.glb", glb(tri_tree(vertex_count=200_000_000),
                                                                             TRI_BIN))}}),
        ("glb with a 16000 x 11000 png", 200, {"url": "/v1/outfits/rig", "files": {"mesh": ("t.glb", textured_glb())}}),
        ("ply declaring 1e9 vertices", 413, {"url": "/v1/outfits/rig", "files": {"mesh": ("a.ply", (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"))}}),
        ("npz with an unused 320 MB member", 422, {"url": "/v1/outfits/rig", "content": npz_with_bomb("unused"),
                                                   "headers": {"content-type": "application/x-npz"}}),
        ("npz whose vertices inflate to 320 MB", 413, {"url": "/v1/outfits/rig", "content": npz_with_bomb("vertices"),
                                                       "headers": {"content-type": "application/x-npz"}}),
        ("multipart declaring 2 GB", 413, {"url": "/v1/outfits/rig", "raw": (
            b"POST /v1/outfits/rig HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=x\r\n"
            b"Content-Length: 2147483648\r\n\r\n--x\r\n")}),
        ("json nested 100,000 deep", 400, {"url": "/v1/outfits/animate", "content": b"[" * 100_000 + b"]" * 100_000,
                                           "headers": {"content-type": "application/json"}}),
        ("10 MiB clip name", 404, {"url": "/v1/outfits/animate", "json": {"outfit_id": "x" * 64,
                                                                          "motion": {"clip": "c" * (10 * MB)}}}),
        ("10,000 frames for an unknown outfit_id", 404, {"url": "/v1/outfits/animate",
                                                         "json": {"outfit_id": "nope", "motion": {"poses": poses}}}),
    ]


def raw_post(url: str, data: bytes) -> httpx.Response:
    """Send raw request bytes on a socket; the answer's status line, headers and body as a Response."""
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as s:
        s.sendall(data)
        answer = b""
        while b"\r\n\r\n" not in answer or len(answer.split(b"\r\n\r\n", 1)[1]) < int(
                [h for h in answer.split(b"\r\n") if h.lower().startswith(b"content-length:")][0].split(b":")[1]):
            chunk = s.recv(65536)
            if not chunk:
                break
            answer += chunk
    head, body = answer.split(b"\r\n\r\n", 1)
    lines = head.decode().split("\r\n")
    headers = dict(line.split(": ", 1) for line in lines[1:])
    return httpx.Response(int(lines[0].split()[1]), headers=headers, content=body)


@pytest.mark.timeout(300)
def test_hostile_inputs_against_a_live_server(settings):
    with served({"DRAPE_MODEL_DIR": str(settings.model_dir)}) as (url, proc):
        with httpx.Client(base_url=url, timeout=30) as c:
            c.post("/v1/outfits/rig", files={"mesh": ("t.glb", glb(tri_tree(), TRI_BIN))}).raise_for_status()
        before = family_rss_mb(proc.pid)
        health: list[float] = []
        done = threading.Event()

        def probe() -> None:
            with httpx.Client(base_url=url, timeout=10) as p:
                while not done.is_set():
                    t = time.perf_counter()
                    assert p.get("/healthz").status_code == 200
                    health.append(time.perf_counter() - t)
                    time.sleep(0.05)

        prober = threading.Thread(target=probe)
        prober.start()
        report = []
        try:
            for name, status, kwargs in cases():
                url_path = kwargs.pop("url")
                t = time.perf_counter()
                if "raw" in kwargs:  # a body shorter than its Content-Length: no HTTP client sends that
                    r = raw_post(url, kwargs["raw"])
                else:
                    with httpx.Client(base_url=url, timeout=30) as c:
                        r = c.post(url_path, **kwargs)
                took = time.perf_counter() - t
                rss = family_rss_mb(proc.pid)
                report.append((name, r.status_code, took, rss))
                assert r.status_code == status, (name, r.text[:300])
                if status >= 400:
                    assert r.headers["content-type"].startswith("application/problem+json")
                    assert len(r.text) < 2000, name  # nothing large echoed back
                assert took < 2.0, (name, took)
                assert rss < 1.2 * before, (name, rss, before)
        finally:
            done.set()
            prober.join()
            print(f"\nRSS before {before:.0f} MB; /healthz max {max(health) * 1000:.0f} ms over {len(health)}")
            for name, code, took, rss in report:
                print(f"{name:40s} {code} {took * 1000:7.1f} ms  RSS {rss:.0f} MB")
        assert proc.poll() is None  # alive
        assert health and max(health) < 1.0
