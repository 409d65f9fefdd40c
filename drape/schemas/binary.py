"""Binary encodings shared by the service and the client (numpy only).

npz (`application/x-npz`): a numpy .npz archive (stored or deflated) of plain arrays;
object (pickled) and void arrays are refused, and `decode_npz` can read just the members it is
asked for and bound their declared sizes before anything is inflated.

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
import math
import struct
import zipfile
import zlib
from collections.abc import Iterable, Iterator
from typing import IO

import numpy as np

MAGIC = b"DRPF"
VERSION = 1
NPZ = "application/x-npz"
FRAMES = "application/x-drape-frames"


def encode_npz(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]  # numpy stubs mistype **kwds
    return buf.getvalue()


MAX_NPZ_MEMBERS = 1024
MAX_NPZ_DIRECTORY_BYTES = 2**20  # the zip central directory (zipfile builds an object per entry)
DEFLATE_MAX_RATIO = 1032  # deflate cannot expand beyond this (258-byte matches in ~2 bits)
MIN_COUNTED_ITEMSIZE = 4  # decode_npz's max_bytes counts every number as at least this many bytes
_READ_CHUNK = 2**20


class NpzTooLarge(ValueError):
    """The npz members asked for declare more bytes than `decode_npz`'s max_bytes."""


def decode_npz(data: bytes, names: Iterable[str] | None = None, *,
               max_bytes: int | None = None) -> dict[str, np.ndarray]:
    """Arrays of an npz, keyed by member name without ".npy"; ValueError for anything else.

    names: read only these members (those present; the others are never opened, so never
    inflated); None reads all. max_bytes: refuse (NpzTooLarge, a ValueError) once the arrays read
    declare more bytes in total, each element counted as at least MIN_COUNTED_ITEMSIZE bytes (readers
    widen numbers to float64 / int64: an int8 array would grow 8-fold past the limit, one of a
    zero-size dtype from nothing; counted so, no array grows more than 2-fold, as float32 does);
    None: no limit. Before a member's data is read its .npy header
    is: object and void dtypes are refused (no pickle is ever loaded), and the bytes it declares
    (shape x itemsize) must equal the zip entry's declared size less the header. zipfile never
    inflates past that declared size (and checks the CRC at its end), and the declared size must
    be one the compressed bytes can produce (stored, or deflate at most 1032:1), so the data
    behind a member costs at most what its bytes can really inflate to. The zip directory is
    bounded too (MAX_NPZ_MEMBERS, MAX_NPZ_DIRECTORY_BYTES; no zip64 end record).
    """
    wanted = None if names is None else set(names)
    try:
        _check_zip_directory(data)
        out: dict[str, np.ndarray] = {}
        total = 0
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            for info in zf.infolist():
                key = info.filename.removesuffix(".npy")
                if wanted is not None and key not in wanted:
                    continue
                if key in out:  # a zip may name two entries alike: which one is meant is anyone's guess
                    raise ValueError(f"member {key!r} is stored more than once")
                if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                    raise ValueError(f"member {key!r} uses zip compression {info.compress_type}; "
                                     "only stored and deflated members are read")
                ratio = 1 if info.compress_type == zipfile.ZIP_STORED else DEFLATE_MAX_RATIO
                possible = info.compress_size * ratio + 1024
                if info.compress_size > len(data) or info.file_size > possible:
                    raise ValueError(f"member {key!r} declares {info.file_size} bytes from "
                                     f"{info.compress_size} compressed bytes, which the archive's "
                                     f"{len(data)} bytes cannot hold")
                with zf.open(info) as f:
                    shape, fortran, dtype, header_bytes = _npy_header(f, key)
                    nbytes = math.prod(shape) * dtype.itemsize
                    counted = math.prod(shape) * max(dtype.itemsize, MIN_COUNTED_ITEMSIZE)
                    total += counted
                    if max_bytes is not None and total > max_bytes:
                        as_ = f", counted as {counted}" if counted != nbytes else ""
                        raise NpzTooLarge(f"member {key!r} declares {shape} {dtype} ({nbytes} "
                                          f"bytes{as_}): the arrays exceed the limit of {max_bytes} "
                                          "bytes")
                    if info.file_size != header_bytes + nbytes:
                        raise ValueError(f"member {key!r}: its header declares {nbytes} bytes "
                                         f"of data but the archive declares {info.file_size} "
                                         f"bytes for the member with its {header_bytes}-byte "
                                         "header")
                    out[key] = _read_npy_data(f, shape, fortran, dtype, nbytes, key)
        return out
    except NpzTooLarge:
        raise
    except Exception as exc:  # zipfile, numpy format and our refusals alike
        raise ValueError(f"not a readable pickle-free npz archive: {exc}") from exc


def _check_zip_directory(data: bytes) -> None:
    """Bound the zip central directory from its end record before zipfile parses it."""
    end = data.rfind(b"PK\x05\x06", max(0, len(data) - 22 - 65535))
    if end < 0 or len(data) - end < 22:
        raise ValueError("not a zip archive (no end-of-central-directory record)")
    _, _, _, _, members, size, _, _ = struct.unpack_from("<4s4H2LH", data, end)
    if end >= 20 and data[end - 20:end - 16] == b"PK\x06\x07":
        raise ValueError("zip64 archives are not read")
    if members > MAX_NPZ_MEMBERS or size > MAX_NPZ_DIRECTORY_BYTES:
        raise ValueError(f"the archive declares {members} members in a {size}-byte directory; "
                         f"at most {MAX_NPZ_MEMBERS} members in {MAX_NPZ_DIRECTORY_BYTES} bytes "
                         "are read")


def _npy_header(f: IO[bytes], key: str) -> tuple[tuple[int, ...], bool, np.dtype, int]:
    """-> (shape, fortran order, dtype, header bytes) of an .npy stream; refuse pickles."""
    try:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
    except ValueError as exc:
        raise ValueError(f"member {key!r} is not a readable .npy array ({exc})") from exc
    if dtype.hasobject or dtype.kind == "V":
        raise ValueError(f"member {key!r} has dtype {dtype}: pickled or object arrays are refused")
    if any(n < 0 for n in shape):
        raise ValueError(f"member {key!r} declares a negative shape {shape}")
    return tuple(shape), bool(fortran), dtype, f.tell()


def _read_npy_data(f: IO[bytes], shape: tuple[int, ...], fortran: bool, dtype: np.dtype,
                   nbytes: int, key: str) -> np.ndarray:
    """Read exactly nbytes into a fresh array, a chunk at a time (no second copy)."""
    flat = np.empty(math.prod(shape), dtype=dtype)
    raw = flat.view(np.uint8) if nbytes else None
    pos = 0
    while pos < nbytes:
        chunk = f.read(min(_READ_CHUNK, nbytes - pos))
        if not chunk:
            raise ValueError(f"member {key!r} ends after {pos} of its {nbytes} bytes")
        assert raw is not None
        raw[pos:pos + len(chunk)] = np.frombuffer(chunk, np.uint8)
        pos += len(chunk)
    if f.read(1):
        raise ValueError(f"member {key!r} holds more than its {nbytes} declared bytes")
    if fortran:
        return flat.reshape(shape[::-1]).transpose()
    return flat.reshape(shape)


def stream_header(num_frames: int, faces: np.ndarray, num_vertices: int, fps: float, outfit_id: str,
                  layers: list[dict] | None = None) -> bytes:
    """layers: for a stream of several garments as one mesh, [{"name", "start", "stop"}] vertex ranges (the
    header's `layers` member, absent otherwise)."""
    fields = {"num_frames": num_frames, "num_vertices": num_vertices, "num_faces": int(len(faces)),
              "fps": fps, "dtype": "<f4", "outfit_id": outfit_id}
    header = json.dumps(fields | ({"layers": layers} if layers else {})).encode()
    return MAGIC + struct.pack("<II", VERSION, len(header)) + header + np.ascontiguousarray(faces, dtype="<i4").tobytes()


def stream_chunk(frames: np.ndarray) -> tuple[bytes, memoryview]:
    """(n, N, 3) -> one chunk as its two parts, the count and the float32 bytes (a view of the array
    when it is already little-endian float32 and contiguous: no copy); n = 0 ends the stream."""
    data = np.ascontiguousarray(frames, dtype="<f4")
    return struct.pack("<I", len(data)), data.data.cast("B") if data.size else memoryview(b"")


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


class FrameReader:
    """A whole frame stream into one array allocated from its header: `vertices` (T, N, 3) float32, each
    payload byte copied once, from the bytes as they arrive (feed them, then check `done`)."""

    def __init__(self) -> None:
        self._head = bytearray()  # the header, faces and a chunk's 4-byte count, as they accumulate
        self.header: dict | None = None
        self.faces: np.ndarray | None = None
        self.vertices: np.ndarray | None = None
        self._out: memoryview | None = None
        self._written = 0
        self._chunk_left = 0  # bytes of the current chunk still to come
        self.done = False

    def _parse_header(self) -> bool:
        buf = self._head
        if len(buf) < 12:
            return False
        if bytes(buf[:4]) != MAGIC:
            raise ValueError("not a drape frame stream")
        version, hlen = struct.unpack("<II", bytes(buf[4:12]))
        if version != VERSION:
            raise ValueError(f"unsupported frame stream version {version}")
        if len(buf) < 12 + hlen:
            return False
        header = json.loads(bytes(buf[12 : 12 + hlen]))
        need = 12 + hlen + 12 * int(header["num_faces"])
        if len(buf) < need:
            return False
        self.faces = np.frombuffer(bytes(buf[12 + hlen : need]), dtype="<i4").reshape(-1, 3)
        self.vertices = np.empty((int(header["num_frames"]), int(header["num_vertices"]), 3), dtype="<f4")
        self._out = self.vertices.reshape(-1).view(np.uint8).data
        del buf[:need]
        self.header = header
        return True

    def feed(self, data: bytes) -> None:
        view = memoryview(data)
        while len(view) and not self.done:
            if self.header is None or self._chunk_left == 0:
                take = 4 - len(self._head) if self.header is not None else len(view)
                self._head += view[:take]
                view = view[take:]
                if self.header is None:
                    if self._parse_header():  # what came after the header goes round again
                        view = memoryview(bytes(self._head))
                        self._head.clear()
                    continue
                if len(self._head) < 4:
                    continue
                (count,) = struct.unpack("<I", bytes(self._head))
                self._head.clear()
                if count == 0:
                    self.done = True
                    if self._out is not None and self._written != len(self._out):
                        raise ValueError(f"the stream ended after {self._written} of {len(self._out)} bytes")
                    break
                self._chunk_left = count * 12 * int(self.header["num_vertices"])
                assert self._out is not None
                if self._written + self._chunk_left > len(self._out):
                    raise ValueError("the stream holds more frames than its header says")
                continue
            assert self._out is not None
            k = min(len(view), self._chunk_left)
            self._out[self._written : self._written + k] = view[:k]
            self._written += k
            self._chunk_left -= k
            view = view[k:]
        if len(view) and self.done:
            raise ValueError("bytes after the end of the frame stream")


class NpzReader:
    """A stored (uncompressed) npz read as its bytes arrive, each array into one array allocated from its
    .npy header: every payload byte copied once, no archive-sized buffer (feed bytes, then check `done`).

    For npz answers of drape's server (numpy's uncompressed layout, sizes and CRCs in data
    descriptors); deflated members are refused (use `decode_npz` on the whole archive). names: keep
    only these members (the others are skipped as they pass); None keeps all. `arrays` maps member
    names (without ".npy") to arrays; `done` turns True at the central directory. Each member's
    CRC-32 is checked against its data descriptor or local header.
    """

    def __init__(self, names: Iterable[str] | None = None, *, max_bytes: int | None = None) -> None:
        self._wanted = None if names is None else set(names)
        self._max_bytes = max_bytes
        self._total = 0
        self._head = bytearray()  # a record header (zip or .npy) as it accumulates
        self._state = "record"
        self._member: dict = {}
        self._out: memoryview | None = None  # where the current member's data goes (None: skipped)
        self._left = 0  # data bytes of the current member still to come
        self._crc = 0
        self.arrays: dict[str, np.ndarray] = {}
        self.done = False

    def feed(self, data: bytes | memoryview) -> None:
        view = memoryview(data).cast("B")
        while len(view) and not self.done:
            if self._state == "data":
                k = min(len(view), self._left)
                if self._out is not None:
                    pos = len(self._out) - self._left
                    self._out[pos:pos + k] = view[:k]
                self._crc = zlib.crc32(view[:k], self._crc)
                self._left -= k
                view = view[k:]
                if self._left == 0:
                    self._state = "descriptor" if self._member["flags"] & 0x08 else "record"
                    if self._state == "record":
                        self._check_crc(self._member["crc"])
                continue
            take = self._need() - len(self._head)
            self._head += view[:take]
            view = view[take:]
            while not self.done and self._state != "data" and len(self._head) == self._need():
                self._advance()

    def _need(self) -> int:
        """Bytes the current header needs in all (it may grow once its length fields have arrived)."""
        h = self._head
        if self._state == "record":
            if len(h) < 4:
                return 4
            if bytes(h[:4]) != b"PK\x03\x04":
                return 4  # the central directory (or junk): _advance decides
            if len(h) < 30:
                return 30
            name_len, extra_len = struct.unpack_from("<HH", h, 26)
            return 30 + name_len + extra_len
        if self._state == "npy":
            if len(h) < 10:
                return 10
            major = h[6]
            if major == 1:
                return 10 + struct.unpack_from("<H", h, 8)[0]
            if len(h) < 12:
                return 12
            return 12 + struct.unpack_from("<I", h, 8)[0]
        # descriptor: optional signature, crc, then 4- or 8-byte sizes
        if len(h) < 4:
            return 4
        sig = 4 if bytes(h[:4]) == b"PK\x07\x08" else 0
        return sig + 4 + (16 if self._member["zip64"] else 8)

    def _advance(self) -> None:
        h = bytes(self._head)
        self._head.clear()
        if self._state == "record":
            if h[:4] in (b"PK\x01\x02", b"PK\x05\x06", b"PK\x06\x06"):
                self.done = True
                return
            if h[:4] != b"PK\x03\x04":
                raise ValueError("not a zip archive: no local file header where one belongs")
            flags, method = struct.unpack_from("<HH", h, 6)
            crc, = struct.unpack_from("<I", h, 14)
            name_len, = struct.unpack_from("<H", h, 26)
            name = h[30:30 + name_len].decode("utf-8", "replace")
            if method != zipfile.ZIP_STORED:
                raise ValueError(f"member {name!r} is compressed (method {method}); NpzReader reads stored "
                                 "members only: use decode_npz")
            self._member = {"key": name.removesuffix(".npy"), "flags": flags, "crc": crc,
                            "zip64": _has_zip64(h[30 + name_len:])}
            self._crc = zlib.crc32(b"")
            self._state = "npy"
            return
        if self._state == "npy":
            key = self._member["key"]
            self._crc = zlib.crc32(h, self._crc)
            shape, fortran, dtype, _ = _npy_header(io.BytesIO(h), key)
            nbytes = math.prod(shape) * dtype.itemsize
            self._out = None
            if self._wanted is None or key in self._wanted:
                self._total += nbytes
                if self._max_bytes is not None and self._total > self._max_bytes:
                    raise NpzTooLarge(f"member {key!r} declares {shape} {dtype} ({nbytes} bytes): the arrays "
                                      f"exceed the limit of {self._max_bytes} bytes")
                flat = np.empty(math.prod(shape), dtype=dtype)
                self.arrays[key] = flat.reshape(shape[::-1]).transpose() if fortran else flat.reshape(shape)
                self._out = flat.view(np.uint8).data if nbytes else memoryview(b"")
            self._left = nbytes
            self._state = "data"
            if nbytes == 0:  # no data bytes will come to move the state on
                self._state = "descriptor" if self._member["flags"] & 0x08 else "record"
                if self._state == "record":
                    self._check_crc(self._member["crc"])
            return
        sig = 4 if h[:4] == b"PK\x07\x08" else 0
        self._check_crc(struct.unpack_from("<I", h, sig)[0])
        self._state = "record"

    def _check_crc(self, expected: int) -> None:
        if self._crc != expected:
            raise ValueError(f"member {self._member['key']!r}: CRC-32 {self._crc:#010x} where the archive "
                             f"says {expected:#010x}")


def _has_zip64(extra: bytes) -> bool:
    """Whether a zip extra field holds a zip64 record (header id 1): sizes in data descriptors are 8 bytes."""
    pos = 0
    while pos + 4 <= len(extra):
        hid, size = struct.unpack_from("<HH", extra, pos)
        if hid == 1:
            return True
        pos += 4 + size
    return False


def read_stream(chunks: Iterable[bytes]) -> tuple[dict, np.ndarray, Iterator[np.ndarray]]:
    """Parse a whole frame stream -> (header, faces (F, 3), iterator of frames (N, 3)) (for tests and tools)."""
    dec = FrameDecoder()
    frames: list[np.ndarray] = []
    for c in chunks:
        frames += dec.feed(c)
    if not dec.done or dec.header is None or dec.faces is None:
        raise ValueError("frame stream ended early")
    return dec.header, dec.faces, iter(frames)
