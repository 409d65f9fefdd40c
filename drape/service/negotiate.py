"""Content negotiation on the Accept header."""

from __future__ import annotations

from drape.service.errors import NotAcceptable


def choose(accept: str | None, offered: list[str]) -> str:
    """The offered media type the Accept header prefers (RFC 9110 12.5.1): each offered type takes the q-value of
    the most specific range that matches it (type/subtype over type/* over */*; an invalid q counts as 0), so
    "application/*, application/json;q=0" rules JSON out; the highest q wins, ties going to the more specific
    match, then to the range written first, then to the order offered (offered[0] for */* or no header)."""
    if not accept or not accept.strip():
        return offered[0]
    ranges: list[tuple[str, float, int]] = []  # (media range, q, position in the header)
    for i, part in enumerate(accept.split(",")):
        fields = [x.strip() for x in part.split(";")]
        media, q = fields[0].lower(), 1.0
        media = "*/*" if media == "*" else media  # a bare "*" (sent by some HTTP libraries) means any type
        for param in fields[1:]:
            name, _, value = param.partition("=")
            if name.strip().lower() == "q":  # parameter names are case-insensitive (RFC 9110 5.6.6)
                try:
                    q = float(value.strip())
                except ValueError:
                    q = 0.0
        ranges.append((media, q if 0.0 <= q <= 1.0 else 0.0, i))
    best: tuple[float, int, int, int] | None = None
    chosen = None
    for j, offer in enumerate(offered):
        match = None  # (specificity, q, header position) of the most specific range matching the offer
        for media, q, i in ranges:
            specificity = 2 if media == offer else 1 if media.endswith("/*") and media != "*/*" and \
                offer.startswith(media[:-1]) else 0 if media == "*/*" else -1
            if specificity >= 0 and (match is None or specificity > match[0]):
                match = (specificity, q, i)
        if match is None or match[1] <= 0:
            continue
        key = (match[1], match[0], -match[2], -j)
        if best is None or key > best:
            best, chosen = key, offer
    if chosen is not None:
        return chosen
    raise NotAcceptable(f"none of {offered} matches Accept: {accept!r}", "Accept")
