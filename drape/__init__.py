"""drape: an inference service for neural garment animation."""

__version__ = "0.1.0"

from drape.client import AsyncClient, Client, DrapeAPIError  # noqa: E402  (numpy, pydantic, httpx only)

__all__ = ["AsyncClient", "Client", "DrapeAPIError", "__version__"]
