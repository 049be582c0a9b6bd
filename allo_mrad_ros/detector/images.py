"""Input checks and conversion of camera and reference images to the detector's layout."""

from __future__ import annotations

import cv2
import numpy as np

from allo_mrad_ros.detector.reference_cache import ReferenceCache, derived

# Multiplier that brings each accepted dtype onto the 0..255 scale of an 8-bit image.
_TO_8BIT_SCALE = {
    np.dtype(np.uint8): 1.0,
    np.dtype(np.uint16): 255.0 / 65535.0,
    np.dtype(np.float32): 255.0,
    np.dtype(np.float64): 255.0,
}


def check_image(image: object, name: str, bit_depth: int = 16) -> np.ndarray:
    """Validate an H x W x 3 colour image and return it on a scale the detector reads.

    Accepted dtypes are uint8, uint16 and float32/float64 (floats on the 0..1 scale).
    A uint16 image carries ``bit_depth`` significant bits (12 for a 12-bit camera): it is
    returned as float32 on the 0..1 scale, ``value / (2**bit_depth - 1)``, so a 12-bit
    image is not read as nearly black.

    Parameters
    ----------
    image : object
        The image to check.
    name : str
        Its name in error messages ("query", "reference").
    bit_depth : int
        Significant bits of uint16 input, 9..16.

    Raises
    ------
    ValueError
        Naming ``name`` and the offending shape, dtype or value: float values outside
        [0, 1] or not finite, uint16 values above ``2**bit_depth - 1``.
    """
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(image).__name__}")
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{name} must have shape (H, W, 3), got {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"{name} is empty: shape {image.shape}")
    if image.dtype not in _TO_8BIT_SCALE:
        raise ValueError(
            f"{name} has unsupported dtype {image.dtype}; use uint8, uint16, float32 or float64"
        )
    if image.dtype.kind == "f":
        low, high = float(image.min()), float(image.max())
        if not (np.isfinite(low) and np.isfinite(high)):
            bad = int(np.count_nonzero(~np.isfinite(image)))
            raise ValueError(f"{name} contains {bad} NaN or Inf value(s)")
        if low < 0.0 or high > 1.0:
            raise ValueError(
                f"{name} is a float image with values in [{low:g}, {high:g}]; float images "
                "must lie in [0, 1] (divide by the white level, or pass uint8/uint16)"
            )
    if image.dtype == np.uint16:
        if not 9 <= bit_depth <= 16:
            raise ValueError(f"bit_depth must be an integer in [9, 16], got {bit_depth!r}")
        white = (1 << bit_depth) - 1
        high = int(image.max())
        if high > white:
            raise ValueError(
                f"{name} is a {bit_depth}-bit uint16 image but holds {high} > {white}; "
                "set bit_depth to the camera's real bit depth"
            )
        return image.astype(np.float32) * np.float32(1.0 / white)
    return image


def to_float32(image: np.ndarray) -> np.ndarray:
    """Return a validated image as C-contiguous float32 on the 0..255 scale."""
    scale = _TO_8BIT_SCALE[image.dtype]
    if scale == 1.0:
        return np.ascontiguousarray(image, dtype=np.float32)
    return np.ascontiguousarray(image * scale, dtype=np.float32)


SPACE_LEVEL = 8.0
"""Brightest channel (8-bit scale) at or below which a reference pixel shows space."""


def eight_bit(image: np.ndarray) -> np.ndarray:
    """A validated image as uint8 on the 8-bit scale (rounded half to even, saturated)."""
    if image.dtype == np.uint8:
        return image
    return cv2.convertScaleAbs(np.maximum(to_float32(image), 0.0, dtype=np.float32))


def brightest_channel(image: np.ndarray) -> np.ndarray:
    """H x W: each pixel's brightest channel."""
    # Elementwise over channels: NumPy's reductions over a length-3 axis are slow.
    return np.maximum(np.maximum(image[..., 0], image[..., 1]), image[..., 2])


def station_surface(reference: np.ndarray) -> np.ndarray:
    """H x W bool: where the reference (8-bit scale) shows station, not space."""
    return brightest_channel(reference) > SPACE_LEVEL


def nearest_resize(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``image`` at ``shape`` = (height, width) by nearest neighbour (itself when it has it)."""
    if image.shape[:2] == shape:
        return image
    return cv2.resize(image, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)


def reference_at(
    reference: np.ndarray,
    shape: tuple[int, int],
    cache: ReferenceCache | None = None,
) -> np.ndarray:
    """The uint8 reference at the query's ``shape`` = (height, width), nearest neighbour (a
    pixel takes one reference colour, not a blend of two materials); kept in ``cache`` while
    the reference is reused, one resize for every stage that reads it."""
    return derived(
        cache,
        reference,
        ("nearest", *shape),
        lambda: nearest_resize(eight_bit(reference), shape),
    )


def check_aspect(query: np.ndarray, reference: np.ndarray) -> None:
    """Require the reference to have the query's aspect ratio within one reference pixel.

    Raises
    ------
    ValueError
        If the aspect ratios disagree.
    """
    hq, wq = query.shape[:2]
    hr, wr = reference.shape[:2]
    if abs(wr - wq * hr / hq) > 1.0 or abs(hr - hq * wr / wq) > 1.0:
        raise ValueError(
            f"reference aspect ratio {wr}x{hr} does not match query {wq}x{hq} "
            "(a reference may be smaller than the query but must have the same aspect ratio)"
        )


def area_downscale(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Average ``image`` down to ``size`` = (width, height) with area (box) weights.

    While the factor is an even integer in both directions the image is halved first,
    through OpenCV's vectorised 2 x 2 path (four times faster at 1080p than its general
    area resampler); whatever factor remains is one general area resize. Boxes of integer
    factors compose into the box of their product, so the result is the one-step area
    average up to the 8-bit rounding of the intermediate images.

    Parameters
    ----------
    image : numpy.ndarray
        H x W x C image, any OpenCV dtype.
    size : tuple of int
        Target (width, height), no larger than the image in either direction.

    Returns
    -------
    numpy.ndarray
    """
    width, height = size
    while image.shape[1] % (2 * width) == 0 and image.shape[0] % (2 * height) == 0:
        half = (image.shape[1] // 2, image.shape[0] // 2)
        image = cv2.resize(image, half, interpolation=cv2.INTER_AREA)
    if (image.shape[1], image.shape[0]) != (width, height):
        image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    return image


# Unsigned types whose bytes are all equal when a byte is multiplied by their 0x0101... .
_WIDE_BYTES = {2: np.uint16, 4: np.uint32, 8: np.uint64}


def nearest_upscale(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Enlarge a 2-D uint8 image to ``shape`` = (height, width) by nearest-neighbour.

    Equal to ``cv2.resize(..., interpolation=cv2.INTER_NEAREST)``. Integer factors replicate
    bytes directly: a row is widened 2, 4 or 8 times by reading each byte as a wider
    integer times 0x0101..., and rows are copied down, ten times faster at 1080p than
    OpenCV's general nearest-neighbour path; other factors use that path.

    Parameters
    ----------
    mask : numpy.ndarray
        H x W uint8.
    shape : tuple of int
        Target (height, width).

    Returns
    -------
    numpy.ndarray
        C-contiguous uint8 of ``shape``.
    """
    height, width = mask.shape
    rows, cols = divmod(shape[0], height), divmod(shape[1], width)
    if rows[1] or cols[1] or mask.dtype != np.uint8:
        return cv2.resize(mask, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    fy, fx = rows[0], cols[0]
    if fx in _WIDE_BYTES:
        wide = _WIDE_BYTES[fx]
        ones = wide(int.from_bytes(b"\x01" * fx, "little"))
        widened = (mask.astype(wide) * ones).view(np.uint8).reshape(height, shape[1])
    else:
        widened = np.repeat(mask, fx, axis=1)
    out = np.empty((height, fy, shape[1]), dtype=np.uint8)
    out[:] = widened[:, None, :]
    return out.reshape(shape)
