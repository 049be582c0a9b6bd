"""A damaged PNG is one error naming the damage, found before OpenCV decodes it: the libpng
of OpenCV 4.6 (Ubuntu 24.04's) prints a line of its own for such a file otherwise."""

import zlib

import cv2
import numpy as np
import pytest

from allo_mrad_ros.sequence import png
from allo_mrad_ros.sequence.model import SequenceError


@pytest.fixture
def written(tmp_path):
    """A PNG written by OpenCV (several IDAT chunks) and its bytes."""
    path = tmp_path / "frame.png"
    rgb = np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    assert cv2.imwrite(str(path), rgb, [cv2.IMWRITE_PNG_COMPRESSION, 0])
    return path, path.read_bytes()


def chunks(data: bytes) -> list[tuple[bytes, int, int]]:
    """(type, start, end) of each chunk: the slow reading of the PNG specification."""
    found, position = [], 8
    while position < len(data):
        length = int.from_bytes(data[position : position + 4], "big")
        found.append((data[position + 4 : position + 8], position, position + 12 + length))
        position += 12 + length
    return found


def test_a_whole_png_has_no_damage_and_decodes(written):
    path, data = written
    assert png.png_damage(np.frombuffer(data, np.uint8)) is None
    assert png.load_rgb(path).shape == (120, 160, 3)


def test_a_cut_png_is_named_truncated_at_its_chunk_without_decoding(written, monkeypatch, capfd):
    path, data = written
    _, start, end = next(c for c in chunks(data) if c[0] == b"IDAT")
    path.write_bytes(data[: (start + end) // 2])
    monkeypatch.setattr(png.cv2, "imdecode", lambda *a: pytest.fail("decoded a damaged file"))
    with pytest.raises(SequenceError, match="truncated PNG: the file ends inside its IDAT chunk"):
        png.load_rgb(path)
    path.write_bytes(data[: chunks(data)[-1][1]])  # all but IEND
    with pytest.raises(SequenceError, match="ends before its IEND chunk"):
        png.load_rgb(path)
    assert capfd.readouterr().err == ""


def test_a_flipped_byte_is_a_wrong_checksum_of_its_chunk(written):
    path, data = written
    _, start, end = next(c for c in chunks(data) if c[0] == b"IDAT")
    damaged = bytearray(data)
    damaged[start + 20] ^= 0xFF
    # The oracle: zlib's CRC of the damaged chunk no longer matches the stored one.
    assert zlib.crc32(damaged[start + 4 : end - 4]) != int.from_bytes(damaged[end - 4 : end], "big")
    path.write_bytes(bytes(damaged))
    with pytest.raises(SequenceError, match="checksum of its IDAT chunk is wrong"):
        png.load_rgb(path)


def test_the_damage_line_is_the_only_output_even_with_opencv_4_6(written, capfd):
    # OpenCV 4.6's libpng writes to the process's stderr (fd 2), past OpenCV's log level.
    path, data = written
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(SequenceError):
        png.load_grey(path)
    assert capfd.readouterr().err == ""
