"""Domain errors raised by the handlers; `problems.py` maps them to HTTP problem documents."""

from __future__ import annotations


class DrapeError(Exception):
    """Base: `field` names the part of the request that is wrong, `detail` says how."""

    def __init__(self, detail: str, field: str | None = None):
        super().__init__(detail)
        self.detail = f"{field}: {detail}" if field else detail
        self.field = field


class InvalidInput(DrapeError):
    """Well-formed but wrong: shapes, non-finite values, indices out of range, degenerate meshes."""


class MalformedInput(DrapeError):
    """Unreadable: broken JSON, mesh files or archives."""


class NotFound(DrapeError):
    """An id or name that does not exist."""


class LimitExceeded(DrapeError):
    """Larger than a configured limit; the detail names the limit."""


class UnsupportedMediaType(DrapeError):
    """A request body in a format the route does not take."""


class NotAcceptable(DrapeError):
    """No answer format matches the Accept header."""


class Unauthorized(DrapeError):
    """Missing or wrong API key."""
