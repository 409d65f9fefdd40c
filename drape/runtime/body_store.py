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
from typing import BinaryIO

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
    """User bodies by name. `add` registers a body (the same arrays give the same name) and counts its
    registrations; `delete` takes one back and forgets the body with the last (two clients that registered the
    same body each hold it until each deletes it); `close` unregisters everything this store registered (the
    files stay). With a directory the counts are kept beside the bodies (`<name>.refs`, when over 1)."""

    def __init__(self, max_count: int, max_bytes: int, directory: Path | None = None,
                 check: Callable[[dict[str, np.ndarray], str], Body] | None = None):
        """check: re-validates a body read back from `directory` (arrays, name) -> Body; a file it refuses
        (ValueError or the service's domain errors) is skipped with a warning."""
        self.max_count, self.max_bytes, self.directory = max_count, max_bytes, directory
        self._bodies: dict[str, Body] = {}
        self._refs: dict[str, int] = {}
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
                self._refs[body.name] = _read_refs(path.with_suffix(".refs"))
            except Exception as exc:  # noqa: BLE001 - a bad file must not stop the service
                log.warning("skipping the stored body %s: %s", path.name, exc)

    def add(self, body: Body, write: bool = True) -> int:
        """Hold `body` under `body.name` (a `body_id`), one registration more -> the body's registrations after
        this one (1: it is new). StoreFull when a new body is over the bounds."""
        size = body_nbytes(body)
        with self._lock:
            if body.name in self._bodies:
                self._set_refs(body.name, self._refs.get(body.name, 1) + 1)
                return self._refs[body.name]
            if len(self._bodies) >= self.max_count:
                raise StoreFull(f"the body store holds its maximum of {self.max_count} bodies: DELETE one")
            if self._bytes + size > self.max_bytes:
                raise StoreFull(f"the body store would hold {self._bytes + size} bytes, over its maximum of "
                                f"{self.max_bytes}: DELETE a body")
            if write and self.directory is not None:
                self._write(body)
            self._bodies[body.name] = body
            self._refs[body.name] = 1
            self._bytes += size
            register_body(body)
            return 1

    def _set_refs(self, name: str, count: int) -> None:
        """A body's registration count, kept on disk too (under the lock; the file only while over 1)."""
        self._refs[name] = count
        if self.directory is None:
            return
        path = self.directory / f"{name}.refs"
        if count > 1:  # durable as the body's file: a count lost in a power cut would let one DELETE forget it
            _replace_durably(path, lambda f: f.write(f"{count}\n".encode()))
        else:
            path.unlink(missing_ok=True)
            _fsync_directory(self.directory)

    def registrations(self, name: str) -> int:
        """How many registrations hold the body (0: not held)."""
        with self._lock:
            return self._refs.get(name, 0) if name in self._bodies else 0

    def _write(self, body: Body) -> None:
        assert self.directory is not None
        _replace_durably(self.directory / f"{body.name}.npz",
                         lambda f: np.savez(f, **_arrays(body)))  # type: ignore[arg-type]

    def get(self, name: str) -> Body | None:
        return self._bodies.get(name)

    def names(self) -> list[str]:
        with self._lock:
            return list(self._bodies)

    def delete(self, name: str) -> bool:
        """Take back one registration of a body, and with the last forget it (and its file); False if this store
        does not hold it."""
        with self._lock:
            if name not in self._bodies:
                return False
            if self._refs.get(name, 1) > 1:
                self._set_refs(name, self._refs[name] - 1)
                return True
            body = self._bodies.pop(name)
            self._refs.pop(name, None)
            self._bytes -= body_nbytes(body)
            unregister_body(name)
            if self.directory is not None:
                (self.directory / f"{name}.npz").unlink(missing_ok=True)
                (self.directory / f"{name}.refs").unlink(missing_ok=True)
                _fsync_directory(self.directory)  # a deleted body stays deleted after a power cut
            return True

    def close(self) -> None:
        with self._lock:
            for name in self._bodies:
                unregister_body(name)
            self._bodies.clear()
            self._refs.clear()
            self._bytes = 0


def _replace_durably(path: Path, write: Callable[[BinaryIO], object]) -> None:
    """Write `path` whole or not at all: `write` fills a temporary file beside it, whose bytes are fsynced before
    the rename and the rename after it (a registered body, or its count, survives a power cut)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())  # the bytes on disk before the name points at them
        os.replace(tmp, path)
        _fsync_directory(path.parent)  # and the rename itself
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _read_refs(path: Path) -> int:
    """A stored body's registration count: its .refs file's number, or 1 without a readable one."""
    try:
        return max(1, int(path.read_text().strip()))
    except (OSError, ValueError):
        return 1


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
