"""Content negotiation on the Accept header."""

from __future__ import annotations

from drape.service.errors import NotAcceptable


def choose(accept: str | None, offered: list[str]) -> str:
    """The offered media type the Accept header prefers (q-values honoured; an invalid one counts as 0); offered[0]
    for */* or none; for a range type/* (model/*, application/*) the first offered type of that type."""
    if not accept or not accept.strip():
        return offered[0]
    ranked: list[tuple[float, int, str]] = []
    for i, part in enumerate(accept.split(",")):
        fields = [x.strip() for x in part.split(";")]
        media, q = fields[0].lower(), 1.0
        for param in fields[1:]:
            name, _, value = param.partition("=")
            if name.strip().lower() == "q":  # parameter names are case-insensitive (RFC 9110 5.6.6)
                try:
                    q = float(value.strip())
                except ValueError:
                    q = 0.0
        ranked.append((q if 0.0 <= q <= 1.0 else 0.0, -i, media))
    for q, _, media in sorted(ranked, reverse=True):
        if q <= 0:
            continue
        if media == "*/*":
            return offered[0]
        if media.endswith("/*"):
            of_type = [o for o in offered if o.startswith(media[:-1])]
            if of_type:
                return of_type[0]
        elif media in offered:
            return media
    raise NotAcceptable(f"none of {offered} matches Accept: {accept!r}", "Accept")
