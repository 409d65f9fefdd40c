"""build/node: the npm packages the tests drive (the glTF validator, three.js, playwright-core), shared by
the test helpers, and one lock so that test processes running side by side (pytest -n) install into it one
at a time (npm and apt-get both break when two run at once)."""

from __future__ import annotations

import fcntl
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

NODE_DIR = Path(__file__).resolve().parents[2] / "build" / "node"


@contextmanager
def installing() -> Iterator[Path]:
    """Hold build/node's install lock (an flock, released when the block ends or the process dies) ->
    the folder, created where missing."""
    NODE_DIR.mkdir(parents=True, exist_ok=True)
    with open(NODE_DIR.parent / "node.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield NODE_DIR
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
