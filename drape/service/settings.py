"""Service settings from the environment (prefix DRAPE_, e.g. DRAPE_PORT=9000, DRAPE_API_KEY=...)."""

from __future__ import annotations

from pathlib import Path

from pydantic_settings import BaseSettings, SettingsConfigDict

from drape.runtime.deepsd import MODEL_DIR


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="DRAPE_")

    host: str = "127.0.0.1"
    port: int = 8000
    model_dir: Path = MODEL_DIR
    ort_threads: int = 2
    max_vertices: int = 100_000
    max_faces: int = 200_000
    max_frames: int = 10_000
    max_posed_values: int = 20_000_000  # frames x vertices in one JSON/npz answer (the stream has no such cap)
    max_body_bytes: int = 64 * 2**20
    outfit_cache_bytes: int = 512 * 2**20
    stream_chunk_frames: int = 32
    refine_workers: int = 2  # processes a chunk's refinement is split over (1: in the serving process)
    api_key: str | None = None
    cors_origins: list[str] = []
