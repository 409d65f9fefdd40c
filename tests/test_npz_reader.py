"""NpzReader (each array into one preallocated array as the bytes arrive) reads what numpy writes and
what the service's streamed npz encoder writes (data descriptors), split anywhere, equal to np.load;
corruption, compression and truncation are errors, never wrong arrays."""

import io
import zipfile

import numpy as np
import pytest

from drape.schemas.binary import NpzReader, NpzTooLarge, encode_npz
from drape.service.answers import FrameSource, encode_npz_stream

ARRAYS = {
    "a": np.arange(12, dtype=np.float32).reshape(3, 4),
    "name": np.array("hello"),
    "empty": np.zeros((0, 3), np.int32),
    "fortran": np.asfortranarray(np.arange(6.0).reshape(2, 3)),
    "scalar": np.array(3.5),
    "big_endian": np.arange(5, dtype=">i4"),
}


def served_npz(frames: np.ndarray, chunk: int = 4) -> bytes:
    faces = np.array([[0, 1, 2], [1, 2, 3]], np.int32)
    src = FrameSource(lambda: iter([frames[i : i + chunk] for i in range(0, len(frames), chunk)]), faces,
                      len(frames), frames.shape[1], 24.0, "abc")
    return b"".join(bytes(p) for p in encode_npz_stream(src))


def read(data: bytes, split: int, names=None) -> NpzReader:
    reader = NpzReader(names)
    for i in range(0, len(data), split):
        reader.feed(data[i : i + split])
    return reader


@pytest.mark.parametrize("split", [1, 5, 64, 4096, 10**9])
def test_numpy_npz_equals_np_load_whatever_the_split(split):
    reader = read(encode_npz(ARRAYS), split)
    assert reader.done and reader.arrays.keys() == ARRAYS.keys()
    for key, want in ARRAYS.items():
        got = reader.arrays[key]
        assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want), key
    assert reader.arrays["fortran"].flags.f_contiguous


@pytest.mark.parametrize("split", [1, 7, 65536])
def test_the_served_npz_with_data_descriptors(split):
    frames = np.random.default_rng(0).normal(size=(23, 5, 3)).astype(np.float32)
    data = served_npz(frames)
    with np.load(io.BytesIO(data)) as z:  # the reference reader
        want = {k: z[k] for k in z.files}
    reader = read(data, split)
    assert reader.done and reader.arrays.keys() == want.keys()
    for key in want:
        assert np.array_equal(reader.arrays[key], want[key]), key
    assert np.array_equal(reader.arrays["vertices"], frames) and reader.arrays["vertices"].flags.writeable


def test_only_the_named_members_are_kept():
    reader = read(encode_npz(ARRAYS), 3, names=["a", "absent"])
    assert reader.done and list(reader.arrays) == ["a"]


class Unseekable(io.RawIOBase):
    """A write-only stream without seek: zipfile then writes sizes and CRCs in data descriptors."""

    def __init__(self) -> None:
        self.data = bytearray()

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:
        self.data += b
        return len(b)

    def tell(self) -> int:
        return len(self.data)


@pytest.mark.parametrize("zip64", [False, True])
def test_data_descriptors_with_and_without_zip64(zip64):
    sink = Unseekable()
    with zipfile.ZipFile(sink, "w", zipfile.ZIP_STORED) as zf, zf.open("v.npy", "w", force_zip64=zip64) as f:
        np.lib.format.write_array(f, np.arange(10, dtype=np.float64))
    data = bytes(sink.data)
    assert data[6] & 0x08  # the data-descriptor flag
    reader = read(data, 3)
    assert reader.done and np.array_equal(reader.arrays["v"], np.arange(10.0))


def test_a_flipped_byte_is_a_crc_error():
    data = bytearray(encode_npz(ARRAYS))
    data[bytes(data).index(ARRAYS["a"].tobytes()) + 5] ^= 1
    with pytest.raises(ValueError, match="CRC-32"):
        read(bytes(data), 100)


def test_deflated_members_are_refused_by_name():
    buf = io.BytesIO()
    np.savez_compressed(buf, v=np.zeros(100))
    with pytest.raises(ValueError, match="'v.npy' is compressed"):
        read(buf.getvalue(), 50)


def test_pickles_are_refused_and_sizes_bounded():
    buf = io.BytesIO()
    np.savez(buf, o=np.array([{"x": 1}], dtype=object))
    with pytest.raises(ValueError, match="pickled or object"):
        read(buf.getvalue(), 50)
    with pytest.raises(NpzTooLarge):
        NpzReader(max_bytes=16).feed(encode_npz({"a": np.zeros(5, np.float32)}))


def test_truncated_archives_are_not_done_and_junk_is_an_error():
    data = encode_npz(ARRAYS)
    assert not read(data[: len(data) // 2], 10).done
    with pytest.raises(ValueError, match="no local file header"):
        read(b"GIF89a" + data, 10)
