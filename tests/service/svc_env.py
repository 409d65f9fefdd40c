"""One freshly initialised exported model per test session (and a small intrinsic garment model, served from
its intrinsic_dir), and the small-limit settings around them."""

import functools
import tempfile
from pathlib import Path

from bench.http import loopback_server as live_server  # noqa: F401  (the tests' live server)
from drape.export.deepsd import export_deepsd_from_checkpoints
from drape.service.settings import Settings
from tests.intrinsic_model import intrinsic_model


@functools.cache
def test_settings() -> Settings:
    out = Path(tempfile.mkdtemp(prefix="drape-model-"))
    export_deepsd_from_checkpoints("unused", out, init=True)
    return Settings(model_dir=out, intrinsic_dir=intrinsic_model().root, max_vertices=3000, max_faces=6000,
                    max_frames=200, max_posed_values=300_000, max_json_values=600_000, max_body_bytes=4 * 2**20,
                    outfit_cache_bytes=64 * 2**20)


PROBLEM = "application/problem+json"


def problem(r, status: int, *words: str) -> dict:
    """The answer `r` is an RFC 9457 problem with this status whose detail names every one of `words`."""
    assert r.status_code == status, r.text[:500]
    assert r.headers["content-type"].startswith(PROBLEM)
    p = r.json()
    assert p["status"] == status and p["type"].startswith("https://drape.dev/problems/") and p["title"]
    for w in words:
        assert w in p["detail"], p["detail"]
    # the field the detail names first is the document's field member (extension, RFC 9457 3.2)
    assert p.get("field") is None or p["detail"].startswith(f"{p['field']}: ") or p["field"].endswith("..."), p
    return p


def assert_a_disconnect_stops_the_work(url: str, path: str, body: dict, accept: str, made: list) -> None:
    """POST `body` to a live server, read the first bytes of the answer and go away: the work (each chunk made
    appends to `made`) stops within a chunk of the disconnect, the cut is counted and the computing slot comes
    back (the route must ask for many more than 4 chunks)."""
    import time

    import httpx

    made.clear()
    with httpx.Client() as c, c.stream("POST", f"{url}{path}", json=body, headers={"accept": accept}) as r:
        assert r.status_code == 200
        next(r.iter_raw())
    time.sleep(1.0)
    assert 1 <= len(made) <= 4, made
    metrics = httpx.get(f"{url}/metrics").text
    assert 'drape_answers_cut_total{reason="disconnected"} 1.0' in metrics
    assert "drape_inflight_requests 0.0" in metrics  # the slot came back
