"""Content negotiation on the Accept header."""

from __future__ import annotations

from drape.service.errors import NotAcceptable


def choose(accept: str | None, offered: list[str]) -> str:
    """The offered media type the Accept header prefers (q-values honoured); offered[0] for */* or none."""
    if not accept or not accept.strip():
        return offered[0]
    ranked: list[tuple[float, int, str]] = []
    for i, part in enumerate(accept.split(",")):
        fields = [x.strip() for x in part.split(";")]
        media, q = fields[0].lower(), 1.0
        for param in fields[1:]:
            if param.startswith("q="):
                try:
                    q = float(param[2:])
                except ValueError:
                    q = 0.0
        ranked.append((q, -i, media))
    for q, _, media in sorted(ranked, reverse=True):
        if q <= 0:
            continue
        if media in ("*/*", "application/*"):
            return offered[0]
        if media in offered:
            return media
    raise NotAcceptable(f"none of {offered} matches Accept: {accept!r}", "Accept")
