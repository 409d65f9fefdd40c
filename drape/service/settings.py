"""Service settings from the environment (prefix DRAPE_, e.g. DRAPE_PORT=9000, DRAPE_API_KEY=...)."""

from __future__ import annotations

from pathlib import Path

from pydantic import field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from drape.runtime.deepsd import MODEL_DIR
from drape.runtime.intrinsic import INTRINSIC_DIR


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="DRAPE_")

    host: str = "127.0.0.1"
    port: int = 8000
    model_dir: Path = MODEL_DIR
    intrinsic_dir: Path = INTRINSIC_DIR  # one folder per intrinsic garment model; missing or empty: no garments
    ort_threads: int = 2
    # what one request may hold
    max_vertices: int = 100_000
    max_faces: int = 200_000
    max_frames: int = 10_000
    max_posed_values: int = 20_000_000  # frames x vertices in one npz answer (the frame stream has no such cap)
    max_json_values: int = 5_000_000  # numbers in one JSON answer; past it a 413 (Accept: */* too) says to ask for npz
    max_body_bytes: int = 64 * 2**20  # request body, multipart uploads included
    max_decoded_bytes: int = 256 * 2**20  # the arrays read from one npz body (as declared, >= 4 bytes a number)
    body_timeout_s: float = 30.0  # the whole request body must arrive within this
    header_timeout_s: float = 10.0  # a new connection must send its request line and headers within this
    # admission control: heavy requests (rig, animate, refine) computing at once, and waiting for a turn
    max_active: int = 2
    max_queue: int = 8
    queue_timeout_s: float = 30.0  # longest wait for a turn before a 503
    retry_after_s: int = 5  # the Retry-After of a 503
    request_budget_s: float = 300.0  # a heavy request's computation stops after this (its answer is cut)
    send_stall_s: float = 30.0  # a streamed answer whose client reads none of it for this long is cut, its slot freed
    # the server
    limit_concurrency: int = 512  # connections + tasks; over it new connections get a 503
    timeout_keep_alive_s: int = 5
    shutdown_grace_s: int = 20  # SIGTERM: in-flight requests get this long, then are cut (below Kubernetes' 30 s;
    # plain `docker stop` waits 10 s: the README's `docker run` sets --stop-timeout 30)
    outfit_cache_bytes: int = 512 * 2**20
    # user bodies (POST /v1/bodies): how many and how many bytes of arrays are kept; kept across restarts
    # only in body_dir (DRAPE_BODY_DIR), one npz per body
    max_bodies: int = 16
    max_body_store_bytes: int = 256 * 2**20
    body_dir: Path | None = None
    stream_chunk_frames: int = 32
    refine_workers: int = 2  # processes a chunk's refinement is split over (1: in the serving process)
    # the served rig's blend shapes fit to keep the garment out of its body (drape.runtime.collision_fit); off: rig
    # requests answer faster (bench.deepsd_collision_fit --latency) with more cloth inside the body
    collision_fit: bool = True
    api_key: str | None = None
    cors_origins: list[str] = []

    @field_validator("api_key")
    @classmethod
    def _api_key_not_empty(cls, value: str | None) -> str | None:
        """An empty DRAPE_API_KEY is a mistake, not a way to turn auth off: refuse to start."""
        if value is not None and not value.strip():
            raise ValueError("DRAPE_API_KEY is set but empty: unset it to serve without auth, or give a key")
        return value
