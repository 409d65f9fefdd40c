"""PointCache2 (`application/x-pc2`): the point-cache format Blender's Mesh Cache modifier, 3ds Max's
Point Cache and Maya's importers read.

Layout, all little-endian: a 32-byte header `char[12] "POINTCACHE2\\0"`, int32 version (1), int32
points N, float32 start frame, float32 sample rate (frames between samples: 1.0, every frame), int32
samples T; then T x N x 3 float32 positions (metres). The format stores no frame rate: a consumer
plays sample t at frame start + t (drape's fps is in its other answers).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator

import numpy as np

PC2 = "application/x-pc2"
SIGNATURE = b"POINTCACHE2\0"
_HEADER = struct.Struct("<12siiffi")  # 32 bytes


def pc2_header(num_points: int, num_samples: int, start_frame: float = 0.0, sample_rate: float = 1.0) -> bytes:
    return _HEADER.pack(SIGNATURE, 1, int(num_points), float(start_frame), float(sample_rate), int(num_samples))


def encode_pc2(chunks: Iterable[np.ndarray], num_points: int, num_samples: int,
               start_frame: float = 0.0) -> Iterator[bytes | memoryview]:
    """The file as pieces: the header, then each chunk (n, N, 3) as float32 bytes (a view when the chunk
    is already little-endian float32 and contiguous). The chunks must hold `num_samples` frames in all."""
    yield pc2_header(num_points, num_samples, start_frame)
    written = 0
    for chunk in chunks:
        data = np.ascontiguousarray(chunk, dtype="<f4")
        if data.ndim != 3 or data.shape[1:] != (num_points, 3):
            raise ValueError(f"chunk of shape {data.shape}, expected (n, {num_points}, 3)")
        written += len(data)
        if data.size:
            yield data.data.cast("B")
    if written != num_samples:
        raise ValueError(f"{written} frames written, the header says {num_samples}")


def read_pc2(data: bytes) -> tuple[np.ndarray, float, float]:
    """-> (positions (T, N, 3) float32, start frame, sample rate); ValueError if it is not a whole PC2."""
    if len(data) < _HEADER.size:
        raise ValueError("shorter than the 32-byte PC2 header")
    sig, version, n, start, rate, t = _HEADER.unpack_from(data)
    if sig != SIGNATURE or version != 1:
        raise ValueError(f"not a PC2 version 1 file (signature {sig!r}, version {version})")
    if n < 0 or t < 0 or len(data) != _HEADER.size + 12 * n * t:
        raise ValueError(f"the header declares {t} samples x {n} points, the file has {len(data) - 32} data bytes")
    return np.frombuffer(data, "<f4", offset=_HEADER.size).reshape(t, n, 3), start, rate
