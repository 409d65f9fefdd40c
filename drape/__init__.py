"""drape: an inference service for neural garment animation."""

__version__ = "0.1.0"

from drape.client import Client  # noqa: E402  (the client needs only numpy, pydantic, httpx)

__all__ = ["Client", "__version__"]
