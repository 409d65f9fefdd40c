"""The user bodies a service holds (registered by `POST /v1/bodies`): bounded by count and bytes, named by a
hash of their arrays, loadable everywhere a body is named while held (`drape.assets.body.register_body`),
and kept in a folder (one npz per body, the presets' file layout) only when one is given.

Arrays of a body: vertices (V, 3) float32 m, faces (F, 3) int32, weights (V, 24) float32 rows summing to 1,
joints (24, 3) float32 m, parents (24,) int32, joint_names (24,) str; T-pose rest, +Y up, facing +Z.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

from drape.assets.body import Body, register_body, unregister_body

PREFIX = "body-"  # every user body's name starts so; presets never do
log = logging.getLogger("drape.bodies")


class StoreFull(Exception):
    """The store holds its maximum count or bytes of bodies; the message says which."""


def body_id(vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray, joints: np.ndarray) -> str:
    """The name a body's arrays get: PREFIX + 16 hex digits of the sha256 of their canonical bytes."""
    h = hashlib.sha256()
    for a, dtype in ((vertices, np.float32), (faces, np.int32), (weights, np.float32), (joints, np.float32)):
        arr = np.ascontiguousarray(a, dtype=dtype)
        h.update(str(arr.shape).encode())
        h.update(arr.tobytes())
    return PREFIX + h.hexdigest()[:16]


def body_nbytes(body: Body) -> int:
    return body.vertices.nbytes + body.faces.nbytes + body.weights.nbytes + body.joints.nbytes


def _arrays(body: Body) -> dict[str, np.ndarray]:
    return {"vertices": body.vertices, "faces": body.faces, "weights": body.weights, "joints": body.joints,
            "parents": body.parents, "joint_names": np.array(body.joint_names, dtype=np.str_)}


class BodyStore:
    """User bodies by name. `add` registers a body (idempotent: the same arrays give the same name);
    `delete` forgets it; `close` unregisters everything this store registered (the files stay)."""

    def __init__(self, max_count: int, max_bytes: int, directory: Path | None = None,
                 check: Callable[[dict[str, np.ndarray], str], Body] | None = None):
        """check: re-validates a body read back from `directory` (arrays, name) -> Body; a file it refuses
        (ValueError or the service's domain errors) is skipped with a warning."""
        self.max_count, self.max_bytes, self.directory = max_count, max_bytes, directory
        self._bodies: dict[str, Body] = {}
        self._bytes = 0
        self._lock = threading.Lock()
        if directory is not None:
            directory.mkdir(parents=True, exist_ok=True)
            self._load(check)

    def _load(self, check: Callable[[dict[str, np.ndarray], str], Body] | None) -> None:
        assert self.directory is not None
        for path in sorted(self.directory.glob(f"{PREFIX}*.npz")):
            try:
                with np.load(path, allow_pickle=False) as z:
                    arrays = {k: z[k] for k in z.files}
                body = check(arrays, path.stem) if check else Body(
                    name=path.stem, vertices=arrays["vertices"], faces=arrays["faces"], weights=arrays["weights"],
                    joints=arrays["joints"], parents=arrays["parents"],
                    joint_names=tuple(str(s) for s in arrays["joint_names"]))
                self.add(body, write=False)
            except Exception as exc:  # noqa: BLE001 - a bad file must not stop the service
                log.warning("skipping the stored body %s: %s", path.name, exc)

    def add(self, body: Body, write: bool = True) -> bool:
        """Hold `body` under `body.name` (a `body_id`); True if it was new. StoreFull when over the bounds."""
        size = body_nbytes(body)
        with self._lock:
            if body.name in self._bodies:
                return False
            if len(self._bodies) >= self.max_count:
                raise StoreFull(f"the body store holds its maximum of {self.max_count} bodies: DELETE one")
            if self._bytes + size > self.max_bytes:
                raise StoreFull(f"the body store would hold {self._bytes + size} bytes, over its maximum of "
                                f"{self.max_bytes}: DELETE a body")
            if write and self.directory is not None:
                self._write(body)
            self._bodies[body.name] = body
            self._bytes += size
            register_body(body)
            return True

    def _write(self, body: Body) -> None:
        assert self.directory is not None
        fd, tmp = tempfile.mkstemp(dir=self.directory, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **_arrays(body))  # type: ignore[arg-type]
                f.flush()
                os.fsync(f.fileno())  # the bytes on disk before the name points at them
            os.replace(tmp, self.directory / f"{body.name}.npz")
            _fsync_directory(self.directory)  # and the rename itself: a registered body survives a power cut
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def get(self, name: str) -> Body | None:
        return self._bodies.get(name)

    def names(self) -> list[str]:
        with self._lock:
            return list(self._bodies)

    def delete(self, name: str) -> bool:
        """Forget a body (and its file); False if this store does not hold it."""
        with self._lock:
            body = self._bodies.pop(name, None)
            if body is None:
                return False
            self._bytes -= body_nbytes(body)
            unregister_body(name)
            if self.directory is not None:
                (self.directory / f"{name}.npz").unlink(missing_ok=True)
                _fsync_directory(self.directory)  # a deleted body stays deleted after a power cut
            return True

    def close(self) -> None:
        with self._lock:
            for name in self._bodies:
                unregister_body(name)
            self._bodies.clear()
            self._bytes = 0


def _fsync_directory(directory: Path) -> None:
    """Make a rename or unlink in `directory` durable (POSIX; a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
