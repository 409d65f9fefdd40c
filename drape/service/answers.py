"""Streaming answers of the frame routes (animate, refine): every format (JSON, npz, the frame stream)
is written chunk by chunk from the computed frames, so an answer's memory is one chunk's, a client that
goes away stops the work within one chunk, and the request's time budget is kept, also against a client that
stops reading (`StallGuardedStream`).

The encoders are plain generators of bytes (no HTTP); `stream_frames` drives one off the event loop.
"""

from __future__ import annotations

import asyncio
import io
import json
import logging
import time
import zipfile
from collections.abc import AsyncIterator, Callable, Generator, Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from drape.schemas.binary import FRAMES, NPZ, stream_chunk, stream_header
from drape.schemas.pc2 import PC2, encode_pc2
from drape.service.admission import Slot
from drape.service.metrics import Metrics

JSON = "application/json"
log = logging.getLogger("drape.service")
Pieces = Generator[bytes | memoryview, None, None]  # an answer's bytes, piece by piece


@dataclass(frozen=True)
class FrameSource:
    """What a frame route answers: `chunks()` yields frames (n, N, 3) float32 metres, T in all, with the
    faces (F, 3) int32 of the garment, the frame rate and the outfit id ('' where no rig of /v1/outfits made the
    stream: refine's, a garment template's, layers'; every frame answer has the same members)."""

    chunks: Callable[[], Iterator[np.ndarray]]
    faces: np.ndarray
    num_frames: int
    num_vertices: int
    fps: float
    outfit_id: str
    layers: list[dict] | None = None  # several garments as one mesh: [{"name", "start", "stop"}] vertex ranges


def _frames32(chunk: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(chunk, dtype="<f4")


def encode_frame_stream(src: FrameSource) -> Pieces:
    """The frame stream (drape.schemas.binary): header and faces, then each chunk as its count and its
    float32 bytes, written from the computed array without a copy; a zero count ends it."""
    yield stream_header(src.num_frames, src.faces, src.num_vertices, src.fps, src.outfit_id, src.layers)
    for chunk in src.chunks():
        yield from stream_chunk(chunk)
    yield stream_chunk(np.zeros((0, src.num_vertices, 3), np.float32))[0]


class _Pieces(io.RawIOBase):
    """A write-only, unseekable file that keeps what is written as pieces for the caller to take."""

    def __init__(self) -> None:
        self.pieces: list[bytes | memoryview] = []
        self.position = 0

    def writable(self) -> bool:
        return True

    def write(self, data) -> int:  # type: ignore[no-untyped-def, override]
        view = memoryview(data).cast("B")
        self.pieces.append(view)
        self.position += len(view)
        return len(view)

    def tell(self) -> int:
        return self.position

    def take(self) -> list[bytes | memoryview]:
        out, self.pieces = self.pieces, []
        return out


def _npz_pieces(small: list[tuple[str, np.ndarray]],
                frames: list[tuple[str, tuple[int, int, int], Iterator[np.ndarray]]]) -> Pieces:
    """numpy's uncompressed npz written as it goes (stored zip members, CRCs in data descriptors; np.load reads
    it): the `small` members (name, array) first, then each `frames` member (name, its shape (T, N, 3), its frames
    (n, N, 3) chunk by chunk), float32, each chunk sent as it is written."""
    sink = _Pieces()
    with zipfile.ZipFile(sink, "w", zipfile.ZIP_STORED) as zf:
        for name, arr in small:
            with zf.open(name + ".npy", "w") as f:
                np.lib.format.write_array(f, np.asarray(arr), allow_pickle=False)
        yield from sink.take()
        for name, shape, chunks in frames:
            with zf.open(name + ".npy", "w", force_zip64=int(np.prod(shape)) * 4 > 2**30) as f:
                np.lib.format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False, "shape": shape})
                for chunk in chunks:
                    f.write(_frames32(chunk).data.cast("B"))
                    yield from sink.take()
    yield from sink.take()


def encode_npz_stream(src: FrameSource) -> Pieces:
    """The npz answer (vertices (T, N, 3) float32, faces, fps float64 (as asked: a float32 read 29.97 as 29.969999),
    outfit_id), written while the frames are computed (`_npz_pieces`)."""
    return _npz_pieces([("faces", src.faces), ("fps", np.array(src.fps, np.float64)),
                        ("outfit_id", np.array(src.outfit_id))],
                       [("vertices", (src.num_frames, src.num_vertices, 3), src.chunks())])


def encode_json(src: FrameSource) -> Pieces:
    """{"outfit_id", "fps", "faces", "vertices"} as JSON text, the vertices written chunk by chunk."""
    head = json.dumps({"outfit_id": src.outfit_id, "fps": src.fps, "faces": src.faces.tolist()})
    yield (head[:-1] + ', "vertices": [').encode()
    first = True
    for chunk in src.chunks():
        text = json.dumps(chunk.tolist())[1:-1]
        if text:
            yield (text if first else "," + text).encode()
            first = False
    yield b"]}"


def encode_pc2_stream(src: FrameSource) -> Pieces:
    """The PC2 point cache (drape.schemas.pc2): its header, then each chunk's float32 bytes as computed."""
    yield from encode_pc2(src.chunks(), src.num_vertices, src.num_frames)


ENCODERS: dict[str, Callable[[FrameSource], Pieces]] = {
    JSON: encode_json, NPZ: encode_npz_stream, FRAMES: encode_frame_stream, PC2: encode_pc2_stream}

LAYER_ROLES = ("inner", "outer")  # a two-layer source's layers, in order (POST /v1/layers/animate)


def _layer_parts(src: FrameSource) -> list[tuple[str, str, int, int, np.ndarray]]:
    """A two-layer source's layers: (role, name, start, stop, faces (Fl, 3) int32 indexing the layer's own
    vertices), from its vertex ranges (`layers`) and the faces of the two as one mesh."""
    assert src.layers is not None and len(src.layers) == len(LAYER_ROLES)
    parts = []
    for role, layer in zip(LAYER_ROLES, src.layers, strict=True):
        start, stop = layer["start"], layer["stop"]
        mine = ((src.faces >= start) & (src.faces < stop)).all(axis=1)
        parts.append((role, layer["name"], start, stop, (src.faces[mine] - start).astype(np.int32)))
    return parts


def _layer_frames(src: FrameSource, parts: list) -> tuple[Iterator[np.ndarray], np.ndarray]:
    """(the first layer's frames (n, N1, 3) chunk by chunk as computed, the array (T, N2, 3) float32 that keeps
    the second layer's frames, filled as the first are taken): the second layer's member is written after the
    first's, so its frames wait in memory, the first's do not."""
    (_, _, s1, e1, _), (_, _, s2, e2, _) = parts
    outer = np.empty((src.num_frames, e2 - s2, 3), np.float32)

    def first() -> Iterator[np.ndarray]:
        t = 0
        for chunk in src.chunks():
            outer[t:t + len(chunk)] = chunk[:, s2:e2]
            t += len(chunk)
            yield chunk[:, s1:e1]

    return first(), outer


def encode_layers_npz(src: FrameSource) -> Pieces:
    """POST /v1/layers/animate's npz answer (inner, outer (text), fps (float64), inner_vertices (T, Ni, 3),
    inner_faces, outer_vertices (T, No, 3), outer_faces), written as the frames are computed: the inner layer's
    frames chunk by chunk, then the outer layer's (kept until then)."""
    parts = _layer_parts(src)
    inner, outer = _layer_frames(src, parts)
    small = [(role, np.array(name)) for role, name, *_ in parts] + [("fps", np.array(src.fps, np.float64))]
    small += [(f"{role}_faces", faces) for role, _, _, _, faces in parts]
    (first, _, s1, e1, _), (second, _, s2, e2, _) = parts
    return _npz_pieces(small, [(f"{first}_vertices", (src.num_frames, e1 - s1, 3), inner),
                               (f"{second}_vertices", (src.num_frames, e2 - s2, 3), iter([outer]))])


def encode_layers_json(src: FrameSource) -> Pieces:
    """POST /v1/layers/animate's JSON answer (LayersAnimateResponse), the inner layer's frames written chunk by
    chunk as computed, then the outer layer's (kept until then)."""
    parts = _layer_parts(src)
    (inner_role, iname, *_), (outer_role, oname, *_) = parts
    head = {inner_role: iname, outer_role: oname, "fps": src.fps,
            **{f"{role}_faces": faces.tolist() for role, _, _, _, faces in parts}}
    yield (json.dumps(head)[:-1] + f', "{inner_role}_vertices": [').encode()
    inner, outer = _layer_frames(src, parts)
    first, step = True, 1
    for frames in inner:
        step = max(step, len(frames))
        text = json.dumps(frames.tolist())[1:-1]
        if text:
            yield (text if first else "," + text).encode()
            first = False
    yield f'], "{outer_role}_vertices": ['.encode()
    for t in range(0, len(outer), step):
        text = json.dumps(outer[t:t + step].tolist())[1:-1]
        yield (text if t == 0 else "," + text).encode()
    yield b"]}"


LAYER_ENCODERS: dict[str, Callable[[FrameSource], Pieces]] = {JSON: encode_layers_json, NPZ: encode_layers_npz}


def encoder(answer: str, src: FrameSource) -> Callable[[FrameSource], Pieces]:
    """The answer's encoder: a two-layer source's JSON and npz answers hold each layer apart (the frame stream,
    PC2: the two as one mesh, the ranges in the stream's header)."""
    if src.layers is not None and answer in LAYER_ENCODERS:
        return LAYER_ENCODERS[answer]
    return ENCODERS[answer]


def first_chunk_ahead(src: FrameSource) -> FrameSource:
    """`src` with its first chunk computed now (every encoder's first piece is a header, before any frame):
    `stream_frames` calls it before the answer starts, so an error in the first chunk is a problem document,
    not a 200 cut short. The rest are computed as the encoder asks for them (the source's chunks() is called once)."""
    rest = src.chunks()
    first = next(rest, None)

    def chunks() -> Iterator[np.ndarray]:
        try:
            if first is not None:
                yield first
            yield from rest
        finally:
            close = getattr(rest, "close", None)
            if close is not None:
                close()

    return replace(src, chunks=chunks)


class _Stalled(Exception):
    """A send did not finish in time: the client stopped reading."""


ABORT_CONNECTION = "drape.abort_connection"  # scope["extensions"]: drops the connection, unsent bytes too (server.py)


class StallGuardedStream(StreamingResponse):
    """A StreamingResponse whose every send, the response's start included, must finish within `stall_s`.

    A client that stops reading fills its TCP window; the server's send then waits on it, and the body generator
    (which checks the time budget between pieces) is never resumed: two such clients held both computing slots
    until they read or left. Here a send that waits longer ends the answer: `stall` says why ("stalled", or
    "time_budget" when it is past `deadline`, time.monotonic()), the body generator is closed, `on_cut(stall)` is
    called (once the generator's own `finally` has run, if it ever started: the caller's cleanup must be
    idempotent), and the connection is dropped where the server offers it (its unsent bytes would otherwise keep
    it open, and a piece in memory, until the client reads or leaves)."""

    def __init__(self, content: AsyncIterator[bytes | memoryview], *, media_type: str, deadline: float,
                 stall_s: float, on_cut: Callable[[str], None]) -> None:
        super().__init__(content, media_type=media_type)
        self.deadline, self.stall_s, self.on_cut = deadline, stall_s, on_cut
        self.stall: str | None = None
        self._abort: Callable[[], None] | None = None

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        self._abort = scope.get("extensions", {}).get(ABORT_CONNECTION)
        await super().__call__(scope, receive, send)

    async def stream_response(self, send: Any) -> None:
        async def guarded(message: Any) -> None:
            try:  # the whole stall_s, even past the deadline: a send that completes at once is never cut here
                await asyncio.wait_for(send(message), timeout=self.stall_s)
            except TimeoutError:
                raise _Stalled from None

        try:
            await super().stream_response(guarded)
        except _Stalled:
            self.stall = "time_budget" if time.monotonic() >= self.deadline else "stalled"
            log.warning("answer cut: a send waited %g s for the client to read (%s)", self.stall_s, self.stall)
            try:
                await self.body_iterator.aclose()  # type: ignore[attr-defined]
            finally:
                self.on_cut(self.stall)
                if self._abort is not None:
                    self._abort()


async def stream_frames(answer: str, src: FrameSource, slot: Slot, budget_s: float,
                        metrics: Metrics, stall_s: float = 30.0) -> StreamingResponse:
    """Drive the answer's encoder off the event loop, one piece at a time, holding `slot` until the end.

    The first chunk's frames (`first_chunk_ahead`) and the first piece are made before the answer starts, so
    an error there is still a problem document. Afterwards, the starlette response cancels this generator when the
    client disconnects: the thread finishes its chunk and nothing more is computed. Past `budget_s` the
    answer is cut (the client sees an incomplete stream) and the cut is counted and logged; so is an answer whose
    client reads none of it for `stall_s` (StallGuardedStream).
    """
    deadline = time.monotonic() + budget_s
    try:
        src = await run_in_threadpool(first_chunk_ahead, src)
    except BaseException:
        slot.release()
        raise
    pieces = encoder(answer, src)(src)

    def next_piece() -> bytes | memoryview | None:
        return next(pieces, None)

    try:
        first = await run_in_threadpool(next_piece)
    except BaseException:
        slot.release()
        pieces.close()
        raise

    ended: list[str] = []

    def finish(end: str) -> None:
        """Count how the answer ended ("": whole) and give back the slot; once, whoever calls first."""
        if ended:
            return
        ended.append(end)
        if end:
            metrics.cut.labels(reason=end).inc()
        slot.release()
        pieces.close()

    async def body() -> AsyncIterator[bytes | memoryview]:
        piece, end = first, "disconnected"  # how the answer ended, unless it finishes
        try:
            while piece is not None:
                yield piece
                if time.monotonic() > deadline:
                    end = "time_budget"
                    log.warning("answer cut: the request's time budget of %g s ran out", budget_s)
                    return
                try:
                    piece = await run_in_threadpool(next_piece)
                except Exception:
                    end = "error"
                    log.exception("answer cut by an error after it started")
                    return
            end = ""
            metrics.served(src.num_frames, src.num_vertices)
        finally:
            finish(response.stall or end)

    response = StallGuardedStream(body(), media_type=answer, deadline=deadline, stall_s=stall_s, on_cut=finish)
    return response
