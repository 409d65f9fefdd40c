"""Python client for the drape service (httpx; depends on drape.schemas only)."""

from __future__ import annotations

import httpx

from drape.schemas.catalog import BodyList, Health, MotionList


class Client:
    """Synchronous client. `Client("http://127.0.0.1:8000")`; use as a context manager or call close()."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, timeout: float = 30.0,
                 transport: httpx.BaseTransport | None = None) -> None:
        self._http = httpx.Client(base_url=base_url, timeout=timeout, transport=transport)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _get(self, path: str) -> dict:
        r = self._http.get(path)
        r.raise_for_status()
        return r.json()

    def health(self) -> Health:
        return Health.model_validate(self._get("/healthz"))

    def bodies(self) -> BodyList:
        return BodyList.model_validate(self._get("/v1/bodies"))

    def motions(self) -> MotionList:
        return MotionList.model_validate(self._get("/v1/motions"))
