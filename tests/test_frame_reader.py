"""FrameReader (one preallocated array) reads what the service's frame stream encoder writes, split
anywhere, exactly as the incremental FrameDecoder does; truncated or overlong streams are errors."""

import numpy as np
import pytest

from drape.schemas.binary import FrameDecoder, FrameReader
from drape.service.answers import FrameSource, encode_frame_stream


def stream_bytes(frames: np.ndarray, chunk: int) -> bytes:
    faces = np.array([[0, 1, 2], [1, 2, 3]], np.int32)
    src = FrameSource(lambda: iter([frames[i : i + chunk] for i in range(0, len(frames), chunk)]), faces,
                      len(frames), frames.shape[1], 24.0, "abc")
    return b"".join(bytes(p) for p in encode_frame_stream(src))


@pytest.mark.parametrize("split", [1, 7, 100, 4096, 10**9])
def test_reader_equals_decoder_whatever_the_split(split):
    frames = np.random.default_rng(0).normal(size=(23, 5, 3)).astype(np.float32)
    data = stream_bytes(frames, chunk=4)
    reader, decoder, got = FrameReader(), FrameDecoder(), []
    for i in range(0, len(data), split):
        reader.feed(data[i : i + split])
        got += decoder.feed(data[i : i + split])
    assert reader.done and decoder.done
    assert reader.header == decoder.header and reader.header["outfit_id"] == "abc"
    assert np.array_equal(reader.faces, decoder.faces)
    assert np.array_equal(reader.vertices, frames) and np.array_equal(np.stack(got), frames)
    assert reader.vertices.flags.writeable


def test_truncated_and_overlong_streams_are_errors():
    frames = np.ones((6, 4, 3), np.float32)
    data = stream_bytes(frames, chunk=2)
    cut = FrameReader()
    cut.feed(data[:-20])
    assert not cut.done
    with pytest.raises(ValueError, match="after the end"):
        FrameReader().feed(data + b"\0")
    header_says_5 = stream_bytes(frames[:5], chunk=2)
    with pytest.raises(ValueError, match="more frames"):
        r = FrameReader()
        r.feed(header_says_5[:-4] + data[-(4 + 4 + 2 * 48):])  # one 2-frame chunk too many
