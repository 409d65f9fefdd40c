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
    return p
