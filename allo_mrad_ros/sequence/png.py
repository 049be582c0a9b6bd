"""PNG access for sequences: header-only checks, decoding and deterministic atomic writes.

The format stores lossless PNG only, so the header check parses the IHDR chunk directly:
it costs one small read per file and needs no image library.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .model import MASK_VALUES, SequenceError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

# PNG colour types (PNG specification, section 11.2.2).
GREY, RGB, PALETTE, GREY_ALPHA, RGBA = 0, 2, 3, 4, 6
_CHANNELS = {GREY: 1, RGB: 3, PALETTE: 1, GREY_ALPHA: 2, RGBA: 4}

# cv2 decodes straight to RGB from OpenCV 4.10 on; older builds need a swap.
_IMREAD_RGB = getattr(cv2, "IMREAD_COLOR_RGB", None)


@dataclass(frozen=True)
class PngHeader:
    """The IHDR fields that matter here."""

    width: int
    height: int
    bit_depth: int
    colour_type: int

    @property
    def is_rgb8(self) -> bool:
        """8-bit RGB or RGBA (alpha is dropped on load)."""
        return self.bit_depth == 8 and self.colour_type in (RGB, RGBA)

    @property
    def is_grey8(self) -> bool:
        """8-bit single channel."""
        return self.bit_depth == 8 and self.colour_type == GREY

    @property
    def is_grey16(self) -> bool:
        """16-bit single channel (instance masks)."""
        return self.bit_depth == 16 and self.colour_type == GREY

    def describe(self) -> str:
        """Human-readable size and pixel layout, for error messages."""
        kind = {
            GREY: "grey",
            RGB: "RGB",
            PALETTE: "palette",
            GREY_ALPHA: "grey+alpha",
            RGBA: "RGBA",
        }.get(self.colour_type, f"colour type {self.colour_type}")
        return f"{self.width}x{self.height} {self.bit_depth}-bit {kind}"


def read_png_header(path: Path) -> PngHeader:
    """Read the size and pixel layout of a PNG file without decoding it.

    Parameters
    ----------
    path : pathlib.Path
        The file.

    Returns
    -------
    PngHeader
        Its IHDR fields.

    Raises
    ------
    SequenceError
        If the file is missing, unreadable or not a PNG (``file`` is set).
    """
    try:
        with Path(path).open("rb") as stream:
            head = stream.read(26)
    except FileNotFoundError:
        raise SequenceError("file not found", file=path) from None
    except OSError as error:
        raise SequenceError(f"cannot read file: {error.strerror}", file=path) from None
    if len(head) < 26 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise SequenceError("not a PNG file", file=path)
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", head[16:26])
    return PngHeader(width, height, bit_depth, colour_type)


def _log_level_functions() -> tuple:
    """OpenCV's log-level getter and setter (``cv2.utils.logging`` in 5.x, top level in 4.x)."""
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging is not None and hasattr(logging, "setLogLevel"):
        return logging.getLogLevel, logging.setLogLevel
    return cv2.getLogLevel, cv2.setLogLevel


def png_damage(data: np.ndarray) -> str | None:
    """Why the chunks of a PNG file's bytes are broken (cut short, a checksum wrong), or None.

    Checked before decoding: for such a file the libpng of OpenCV 4.6 (Ubuntu 24.04's) prints
    its own ``libpng error`` line on stderr, which OpenCV's log level does not silence.

    Parameters
    ----------
    data : numpy.ndarray
        The file's bytes (uint8), signature included.
    """
    raw = memoryview(data).cast("B")
    position = len(PNG_SIGNATURE)
    while position + 8 <= len(raw):
        length, kind = struct.unpack(">I4s", raw[position : position + 8])
        name = kind.decode("latin-1")
        end = position + 12 + length
        if end > len(raw):
            return f"truncated PNG: the file ends inside its {name} chunk"
        (stored,) = struct.unpack(">I", raw[end - 4 : end])
        if zlib.crc32(raw[position + 4 : end - 4]) != stored:
            return f"corrupt PNG: the checksum of its {name} chunk is wrong"
        if kind == b"IEND":
            return None
        position = end
    return "truncated PNG: the file ends before its IEND chunk"


def _decode(path: Path, flags: int) -> np.ndarray:
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except FileNotFoundError:
        raise SequenceError("file not found", file=path) from None
    except OSError as error:
        raise SequenceError(f"cannot read file: {error.strerror}", file=path) from None
    damage = png_damage(data) if data[:8].tobytes() == PNG_SIGNATURE else None
    if damage is not None:
        raise SequenceError(f"cannot decode image: {damage}", file=path)
    # A corrupt file is reported below as one SequenceError; OpenCV's own warning line
    # would only come first and confuse.
    get_level, set_level = _log_level_functions()
    previous = get_level()
    set_level(0)  # LOG_LEVEL_SILENT in every OpenCV version
    try:
        image = cv2.imdecode(data, flags) if data.size else None
    finally:
        set_level(previous)
    if image is None:
        raise SequenceError("cannot decode image", file=path)
    return image


def load_rgb(path: Path) -> np.ndarray:
    """Decode an image file to an RGB uint8 array of shape (H, W, 3)."""
    if _IMREAD_RGB is not None:
        return _decode(path, _IMREAD_RGB)
    return cv2.cvtColor(_decode(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _load_single_channel(path: Path, dtype: type[np.integer]) -> np.ndarray:
    image = _decode(path, cv2.IMREAD_UNCHANGED)
    if image.ndim != 2 or image.dtype != dtype:
        bits = 8 * np.dtype(dtype).itemsize
        raise SequenceError(
            f"expected a {bits}-bit single-channel image, got shape {image.shape} {image.dtype}",
            file=path,
        )
    return image


def load_grey(path: Path) -> np.ndarray:
    """Decode a single-channel 8-bit PNG to a uint8 array of shape (H, W)."""
    return _load_single_channel(path, np.uint8)


def load_grey16(path: Path) -> np.ndarray:
    """Decode a single-channel 16-bit PNG (an instance mask) to uint16 (H, W)."""
    return _load_single_channel(path, np.uint16)


def bad_mask_values(mask: np.ndarray) -> list[int]:
    """Return the sorted values of ``mask`` that are not mask classes (0, 1, 2)."""
    present = np.flatnonzero(np.bincount(mask.ravel(), minlength=256))
    return [int(v) for v in present if v not in MASK_VALUES]


def encode_png(image: np.ndarray, compression: int) -> bytes:
    """Encode an RGB (H, W, 3) or grey (H, W) uint8 array, or a grey uint16 one, as PNG bytes.

    The bytes depend only on the pixels and ``compression`` (no timestamps or text chunks),
    so the same input always gives the same file.
    """
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buffer = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise SequenceError(f"PNG encoding failed for an array of shape {image.shape}")
    return buffer.tobytes()


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary name and a rename.

    A reader never sees a half-written file under the final name, even if the process dies.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        temporary.write_bytes(data)
        temporary.replace(path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
