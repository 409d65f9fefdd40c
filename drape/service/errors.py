"""Domain errors raised by the handlers; `problems.py` maps them to HTTP problem documents."""

from __future__ import annotations

DETAIL_CHARS = 160  # a value quoted in a detail is cut to this many characters


def quoted(value: object, limit: int = DETAIL_CHARS) -> str:
    """repr(value) cut to `limit` characters, so that no detail echoes a large input back."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def field_name(path: tuple | list) -> str:
    """A location in the request as the service names fields everywhere: ("keyframes", 0, "frame") ->
    "keyframes[0].frame" (pydantic's own "keyframes.0.frame" differed from the names the handlers give)."""
    out = ""
    for x in path:
        out += f"[{x}]" if isinstance(x, int) else (f".{x}" if out else str(x))
    return out


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


class RequestTimeout(DrapeError):
    """The request body did not arrive within the time limit."""


class LimitExceeded(DrapeError):
    """Larger than a configured limit; the detail names the limit."""


class Conflict(DrapeError):
    """The request conflicts with what the resource is (e.g. deleting a preset body)."""


class StoreIsFull(DrapeError):
    """A bounded store (user bodies) holds its maximum: delete something first."""


class UnsupportedMediaType(DrapeError):
    """A request body in a format the route does not take."""


class NotAcceptable(DrapeError):
    """No answer format matches the Accept header."""


class Unauthorized(DrapeError):
    """Missing or wrong API key."""


class Overloaded(DrapeError):
    """Every computing slot and queue place is taken (or the wait was too long): retry later."""

    def __init__(self, detail: str, retry_after_s: int):
        super().__init__(detail)
        self.retry_after_s = retry_after_s
