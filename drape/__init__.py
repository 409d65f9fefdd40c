"""drape: an inference service for neural garment animation.

`from drape import Client` works as before; the client (numpy, pydantic, httpx) is imported on first use,
so the training and simulation commands import none of the client's dependencies.
"""

from typing import TYPE_CHECKING

__version__ = "0.1.0"

if TYPE_CHECKING:
    from drape.client import AsyncClient, Client, DrapeAPIError, DrapeWarning

__all__ = ["AsyncClient", "Client", "DrapeAPIError", "DrapeWarning", "__version__"]


def __getattr__(name: str):
    if name in ("AsyncClient", "Client", "DrapeAPIError", "DrapeWarning"):
        import drape.client

        return getattr(drape.client, name)
    raise AttributeError(f"module 'drape' has no attribute {name!r}")
