"""Service settings from the environment (prefix DRAPE_)."""

from __future__ import annotations

from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="DRAPE_")

    host: str = "127.0.0.1"
    port: int = 8000
    cors_origins: list[str] = []
