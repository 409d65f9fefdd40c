"""GET /viewer/: a page that plays drape's animate GLB in the browser with three.js (body, garment, orbit
controls, play/pause, a frame slider), and the few generated outfits it offers.

Everything the page loads comes from this service: its files and three.js r187 (npm `three` 0.187.0: the
module build, GLTFLoader with the two utilities it imports, OrbitControls, and three.js's LICENSE) are
vendored under drape/service/static/viewer/. The page calls the /v1 routes like any client (with the API
key typed into it when the service has one); these routes need no key and stay out of the OpenAPI schema.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse, PlainTextResponse, RedirectResponse, Response

from drape.assets.outfits import generate_outfit
from drape.service.errors import NotFound, quoted

STATIC = Path(__file__).resolve().parents[1] / "static" / "viewer"
TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css"}
# the page's files by their path under /viewer/: a fixed set, so no request path reaches the disk
FILES = {p.relative_to(STATIC).as_posix(): p for p in STATIC.rglob("*") if p.is_file()}
OUTFIT_TYPES = ("tshirt", "dress", "trousers", "skirt")
OUTFIT_VERTICES = 2500  # about; under the smallest limit the tests serve with (3,000)

router = APIRouter(tags=["viewer"], include_in_schema=False)


@router.get("/viewer")
async def viewer_root() -> RedirectResponse:
    """To /viewer/, so that the page's relative addresses work under any prefix."""
    return RedirectResponse("viewer/", status_code=308)


@router.get("/viewer/")
async def viewer_page() -> FileResponse:
    return FileResponse(FILES["index.html"], media_type=TYPES[".html"])


@lru_cache(maxsize=len(OUTFIT_TYPES))
def outfit_obj(kind: str) -> str:
    """A generated outfit (seed 0, ~2,500 vertices, on the neutral body, rest pose) as OBJ text."""
    o = generate_outfit(kind, vertices=OUTFIT_VERTICES, seed=0)
    lines = [f"# drape generated outfit: {kind}, seed 0"]
    lines += [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in o.vertices.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in o.faces.tolist()]
    return "\n".join(lines) + "\n"


@router.get("/viewer/outfits/{kind}.obj")
def viewer_outfit(kind: str) -> PlainTextResponse:
    """One of OUTFIT_TYPES as OBJ (computed once per type; a sync route: off the event loop)."""
    if kind not in OUTFIT_TYPES:
        raise NotFound(f"unknown outfit {quoted(kind)}; the viewer offers {', '.join(OUTFIT_TYPES)}", "kind")
    return PlainTextResponse(outfit_obj(kind), media_type="model/obj")


@router.get("/viewer/{path:path}")
async def viewer_file(path: str) -> Response:
    file = FILES.get(path)
    if file is None:
        raise NotFound(f"no viewer file {quoted(path)}", "path")
    return FileResponse(file, media_type=TYPES.get(file.suffix, "text/plain; charset=utf-8"))
