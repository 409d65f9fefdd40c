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


def cpu_session(blob: bytes, threads: int, arena: bool = True) -> Any:
    """An ONNX Runtime session of an ONNX file's bytes on the CPU: `threads` intra-op threads, one inter-op.
    arena False: no CPU memory arena, so what a run allocates goes back when it ends (for a network whose
    memory grows with the request: DeePSD's outfit network on a 48k-vertex garment kept 716 MB after its run
    with the arena, 35 MB without, in the same time, `bench.rig_scale`)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.enable_cpu_mem_arena = arena
    return ort.InferenceSession(blob, opts, providers=["CPUExecutionProvider"])
