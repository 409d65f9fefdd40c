"""A model folder's files, read and checked against its manifest's sha256, and ONNX Runtime CPU sessions."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path
from typing import Any


def checked_files(folder: str | Path, manifest: dict, keys: Iterable[str]) -> dict[str, bytes]:
    """{key: bytes of manifest["files"][key]["file"] under folder}, each checked against the entry's sha256
    (ValueError naming the file where it does not match)."""
    folder = Path(folder)
    blobs = {}
    for key in keys:
        entry = manifest["files"][key]
        blob = (folder / entry["file"]).read_bytes()
        digest = hashlib.sha256(blob).hexdigest()
        if digest != entry["sha256"]:
            raise ValueError(f"{folder / entry['file']}: sha256 {digest} does not match the manifest")
        blobs[key] = blob
    return blobs


def cpu_session(blob: bytes, threads: int) -> Any:
    """An ONNX Runtime session of an ONNX file's bytes on the CPU: `threads` intra-op threads, one inter-op."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    return ort.InferenceSession(blob, opts, providers=["CPUExecutionProvider"])
