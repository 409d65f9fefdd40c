"""Binary encodings shared by the service and the client (numpy only).

npz (`application/x-npz`): an uncompressed numpy .npz archive of plain arrays;
read with allow_pickle=False, so object arrays are refused.

Frame stream (`application/x-drape-frames`), all integers little-endian:
  magic  b"DRPF", u32 version (1), u32 header length H, H bytes of UTF-8 JSON header
         {"num_frames": T, "num_vertices": N, "num_faces": F, "fps": float,
          "dtype": "<f4", "outfit_id": str};
  faces  F * 3 little-endian int32;
  chunks repeated: u32 n (frames in the chunk), then n * N * 3 little-endian float32;
  end    a chunk with n = 0.
A client can use each chunk as it arrives; the server computes chunk by chunk.
"""

from __future__ import annotations

import io
import json
import struct
from collections.abc import Iterable, Iterator

import numpy as np

MAGIC = b"DRPF"
VERSION = 1
NPZ = "application/x-npz"
FRAMES = "application/x-drape-frames"


def encode_npz(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]  # numpy stubs mistype **kwds
    return buf.getvalue()


def decode_npz(data: bytes) -> dict[str, np.ndarray]:
    """Arrays of an npz; ValueError for anything that is not a pickle-free npz."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception as exc:  # zipfile, numpy format and pickle refusals alike
        raise ValueError(f"not a readable pickle-free npz archive: {exc}") from exc


def stream_header(num_frames: int, faces: np.ndarray, num_vertices: int, fps: float, outfit_id: str) -> bytes:
    header = json.dumps({"num_frames": num_frames, "num_vertices": num_vertices, "num_faces": int(len(faces)),
                         "fps": fps, "dtype": "<f4", "outfit_id": outfit_id}).encode()
    return MAGIC + struct.pack("<II", VERSION, len(header)) + header + np.ascontiguousarray(faces, dtype="<i4").tobytes()


def stream_chunk(frames: np.ndarray) -> bytes:
    """(n, N, 3) -> one chunk; n = 0 (an empty array) ends the stream."""
    return struct.pack("<I", len(frames)) + np.ascontiguousarray(frames, dtype="<f4").tobytes()


class FrameDecoder:
    """Incremental frame-stream parser: feed() bytes as they arrive, get whole frames back.

    After the header has arrived, `header` (dict) and `faces` (F, 3) int32 are set;
    `done` turns True at the end marker.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.header: dict | None = None
        self.faces: np.ndarray | None = None
        self.done = False
        self._frames_left = 0

    def _take(self, n: int) -> bytes | None:
        if len(self._buf) < n:
            return None
        out = bytes(self._buf[:n])
        del self._buf[:n]
        return out

    def feed(self, data: bytes) -> list[np.ndarray]:
        """Add bytes; return the frames (N, 3) float32 completed by them."""
        self._buf += data
        out: list[np.ndarray] = []
        while not self.done:
            if self.header is None:
                if len(self._buf) < 12:
                    break
                if bytes(self._buf[:4]) != MAGIC:
                    raise ValueError("not a drape frame stream")
                version, hlen = struct.unpack("<II", bytes(self._buf[4:12]))
                if version != VERSION:
                    raise ValueError(f"unsupported frame stream version {version}")
                if len(self._buf) < 12 + hlen:
                    break
                header = json.loads(bytes(self._buf[12 : 12 + hlen]))
                need = 12 + hlen + 12 * int(header["num_faces"])
                if len(self._buf) < need:
                    break
                self.faces = np.frombuffer(bytes(self._buf[12 + hlen : need]), dtype="<i4").reshape(-1, 3)
                del self._buf[:need]
                self.header = header
                continue
            frame_bytes = 12 * int(self.header["num_vertices"])
            if self._frames_left == 0:
                count = self._take(4)
                if count is None:
                    break
                (self._frames_left,) = struct.unpack("<I", count)
                if self._frames_left == 0:
                    self.done = True
                    break
            block = self._take(frame_bytes)
            if block is None:
                break
            out.append(np.frombuffer(block, dtype="<f4").reshape(-1, 3))
            self._frames_left -= 1
        return out


def read_stream(chunks: Iterable[bytes]) -> tuple[dict, np.ndarray, Iterator[np.ndarray]]:
    """Parse a whole frame stream -> (header, faces (F, 3), iterator of frames (N, 3)) (for tests and tools)."""
    dec = FrameDecoder()
    frames: list[np.ndarray] = []
    for c in chunks:
        frames += dec.feed(c)
    if not dec.done or dec.header is None or dec.faces is None:
        raise ValueError("frame stream ended early")
    return dec.header, dec.faces, iter(frames)
