"""Stage 0: colour transfer between the rendered reference and the camera's query.

A rasteriser and a camera (or a path tracer) disagree on colour in ways a per-channel gain
and offset cannot follow: a tone curve, a hue that shifts per material, black shadows where
the render shows ambient grey. Every frame pairs the reference with the query, pixel for
pixel at the reference's resolution (the query area-averaged down to it), and learns a 3-D
look-up table from reference colour to query colour:

* the pairs near reference edges are left out (a pose error moves edges; there the pair
  holds two materials);
* the reference colours are binned on nested grids (coarsest first: the whole cube, then
  bins 64, 32, ... ``finest_bin`` levels wide per channel);
* each bin's offset ``query - reference`` is the per-channel median of its pairs, so an
  object that covers less than half of a bin's pairs does not move it; a bin with fewer than
  ``min_count`` pairs takes the offset of the finest enclosing bin that has enough.

The table is applied to either image (``direction``): ``reference`` adds each reference
pixel's offset to it, so the reference takes the query's colours; ``query`` subtracts from
each query pixel the offset of the reference colour at the same place, so the query takes
the reference's colours and the reference's own cell statistics stay what they were (they
can be reused while the reference is).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_edges
from allo_mrad_ros.detector.images import area_downscale, to_float32

__all__ = [
    "ColourTransfer",
    "ColourTransferError",
    "apply_to_query",
    "apply_to_reference",
    "clip_glare",
    "fit_colour_transfer",
]

DIRECTIONS = ("reference", "query")
# Bin widths of the nested grids, coarsest first (256 = one bin: the frame's median offset).
_WIDTHS = (256, 64, 32, 16, 8, 4)
# A reference pixel is "at an edge" where its 3 x 3 (grown by the margin) neighbourhood spans
# more than this many 8-bit levels in some channel.
_EDGE_LEVELS = 48.0
# A reference pixel at most this bright on every channel is space, not station surface.
_SPACE_LEVEL = 8.0
# Pixels around clipped query pixels that count as glare too.
_GLARE_MARGIN = 2


class ColourTransferError(ValueError):
    """The colour transfer cannot run with these inputs or parameters."""


@dataclass(frozen=True)
class ColourTransfer:
    """A fitted reference-to-query colour table.

    Attributes
    ----------
    lut : numpy.ndarray
        (n, n, n, 3) float32 offsets (query minus reference, 8-bit units) per finest bin,
        ``n = 256 // bin_width``, indexed by the reference colour's bin in R, G, B.
    bin_width : int
        Width of the finest bins in 8-bit levels.
    pairs : int
        Pixel pairs the fit used (after the edge exclusion).
    """

    lut: np.ndarray
    bin_width: int
    pairs: int

    def offsets(self, reference: np.ndarray) -> np.ndarray:
        """Per-pixel offsets (H x W x 3 float32) for an 8-bit-scale reference image."""
        bins = _bin_index(reference, self.bin_width)
        n = 256 // self.bin_width
        flat = self.lut.reshape(n * n * n, 3)
        return flat[bins]


def fit_colour_transfer(
    query: np.ndarray,
    reference: np.ndarray,
    finest_bin: int = 16,
    min_count: int = 16,
    edge_margin: int = 0,
) -> ColourTransfer:
    """Fit the reference-to-query colour table of one frame.

    Parameters
    ----------
    query, reference : numpy.ndarray
        Validated H x W x 3 images with the same aspect ratio (any resolutions, any accepted
        dtype); the larger is area-averaged to the smaller's size.
    finest_bin : int
        Width of the finest colour bins, one of 4, 8, 16, 32, 64.
    min_count : int
        Pairs a bin needs to have an offset of its own, >= 1.
    edge_margin : int
        Pixels around reference edges left out of the fit, 0..16.

    Returns
    -------
    ColourTransfer

    Raises
    ------
    ColourTransferError
        For an invalid parameter.
    """
    if finest_bin not in _WIDTHS[1:]:
        raise ColourTransferError(
            f"transfer_bin must be one of {list(_WIDTHS[1:])}, got {finest_bin!r}"
        )
    if isinstance(min_count, bool) or not isinstance(min_count, int) or min_count < 1:
        raise ColourTransferError(f"transfer_min_count must be an integer >= 1, got {min_count!r}")
    if isinstance(edge_margin, bool) or not isinstance(edge_margin, int):
        raise ColourTransferError(f"transfer_edge_margin must be an integer, got {edge_margin!r}")
    if not 0 <= edge_margin <= 16:
        raise ColourTransferError(f"transfer_edge_margin must be in [0, 16], got {edge_margin}")
    query8, reference8 = _paired(query, reference)
    keep = ~_near_edges(reference8, edge_margin)
    if not keep.any():
        keep[:] = True
    ref_pixels = reference8[keep]
    offsets = query8[keep] - ref_pixels
    lut = _nested_medians(ref_pixels, offsets, finest_bin, min_count)
    return ColourTransfer(lut=lut, bin_width=finest_bin, pairs=int(ref_pixels.shape[0]))


def apply_to_reference(reference: np.ndarray, transfer: ColourTransfer) -> np.ndarray:
    """The reference in the query's colours: ``reference + offset(reference)``, uint8."""
    pixels = _eight_bit(reference)
    mapped = pixels + transfer.offsets(pixels)
    return _to_uint8(mapped)


def clip_glare(query: np.ndarray, reference: np.ndarray, level: float) -> np.ndarray:
    """The query with glare (see :func:`apply_to_query`) replaced by the reference's colour.

    For the ``reference`` direction, where the reference already carries the query's
    colours. Returns a uint8 image of the query's size.
    """
    height, width = query.shape[:2]
    pixels = _eight_bit(reference)
    if pixels.shape[:2] != (height, width):
        pixels = cv2.resize(pixels, (width, height), interpolation=cv2.INTER_NEAREST)
    values = _eight_bit(query)
    glare = _glare(values, pixels, level)
    values[glare] = pixels[glare]
    return _to_uint8(values)


def apply_to_query(
    query: np.ndarray,
    reference: np.ndarray,
    transfer: ColourTransfer,
    glare_level: float = 256.0,
    gain: np.ndarray | None = None,
) -> np.ndarray:
    """The query in the reference's colours: ``r + (query - r - offset(r)) / gain``.

    ``r`` is the reference colour at the same pixel: the reference is resized to the
    query's size (nearest neighbour: a pixel takes one reference colour, not a blend of two
    materials). Where the query is what the reference predicts (``r + offset(r)``) it
    becomes ``r``; what departs from the prediction keeps its departure, divided by the
    local contrast gain, so an object keeps its contrast in the reference's units (a darker
    exposure does not shrink it).

    Parameters
    ----------
    query, reference : numpy.ndarray
        Validated images with the same aspect ratio.
    transfer : ColourTransfer
        The frame's fitted table.
    gain : numpy.ndarray, optional
        (G*G, 3) per-cell, per-channel contrast gain of the query over the reference (as
        :func:`~allo_mrad_ros.detector.photometric.fit_cell_affine` fits it); 1 if omitted.
    glare_level : float
        A query pixel whose every channel reaches this level (8-bit scale) over station
        surface (a reference pixel that is not black) is clipped: it says "brighter than
        white", not which colour, so it takes the reference's colour. 256 disables it.

    Returns
    -------
    numpy.ndarray
        uint8 image of the query's size.
    """
    height, width = query.shape[:2]
    pixels = _eight_bit(reference)
    if pixels.shape[:2] != (height, width):
        pixels = cv2.resize(pixels, (width, height), interpolation=cv2.INTER_NEAREST)
    values = _eight_bit(query)
    departure = values - pixels - transfer.offsets(pixels)
    if gain is not None:
        departure /= _per_pixel(gain, height, width)
    mapped = pixels + departure
    if glare_level < 256.0:
        glare = _glare(values, pixels, glare_level, departure)
        mapped[glare] = pixels[glare]
    return _to_uint8(mapped)


def _per_pixel(cells: np.ndarray, height: int, width: int) -> np.ndarray:
    grid = round(np.sqrt(cells.shape[0]))
    rows = np.searchsorted(cell_edges(height, grid), np.arange(height), side="right") - 1
    cols = np.searchsorted(cell_edges(width, grid), np.arange(width), side="right") - 1
    table = cells.reshape(grid, grid, 3).astype(np.float32)
    return table[rows[:, None], cols[None, :]]


def _glare(
    query: np.ndarray, reference: np.ndarray, level: float, departure: np.ndarray | None = None
) -> np.ndarray:
    # Glare bleeds past the clipped pixels (a lens's flare, a sensor's bloom): its border,
    # _GLARE_MARGIN pixels wide, goes with it where it brightened every channel.
    darkest = np.minimum(np.minimum(query[..., 0], query[..., 1]), query[..., 2])
    clipped = darkest >= level
    surface = reference.max(axis=2) > _SPACE_LEVEL
    if clipped.any():
        size = 2 * _GLARE_MARGIN + 1
        near = cv2.dilate(clipped.astype(np.uint8), np.ones((size, size), np.uint8)) > 0
        if departure is not None:
            brighter = (departure >= 0.0).all(axis=2)
            clipped = clipped | (near & brighter)
        else:
            clipped = near
    return clipped & surface


def _paired(query: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    hq, wq = query.shape[:2]
    hr, wr = reference.shape[:2]
    if hq * wq > hr * wr:
        query = area_downscale(query, (wr, hr))
    elif hr * wr > hq * wq:
        reference = area_downscale(reference, (wq, hq))
    return _eight_bit(query), _eight_bit(reference)


def _eight_bit(image: np.ndarray) -> np.ndarray:
    # float32 on the 0..255 scale whatever the input dtype (check_image's conventions).
    return to_float32(image)


def _to_uint8(pixels: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(pixels), 0, 255).astype(np.uint8)


def _near_edges(reference: np.ndarray, margin: int) -> np.ndarray:
    kernel = np.ones((3 + 2 * margin, 3 + 2 * margin), np.uint8)
    spread = cv2.dilate(reference, kernel) - cv2.erode(reference, kernel)
    return spread.max(axis=2) > _EDGE_LEVELS


def _bin_index(pixels: np.ndarray, width: int) -> np.ndarray:
    n = 256 // width
    bins = np.clip(pixels, 0, 255).astype(np.int32) // width
    return (bins[..., 0] * n + bins[..., 1]) * n + bins[..., 2]


def _nested_medians(
    ref_pixels: np.ndarray, offsets: np.ndarray, finest: int, min_count: int
) -> np.ndarray:
    n_fine = 256 // finest
    fine = np.indices((n_fine, n_fine, n_fine)).reshape(3, -1).T  # finest bin coordinates
    lut = np.zeros((n_fine**3, 3), np.float32)
    for width in _WIDTHS[: _WIDTHS.index(finest) + 1]:
        n = 256 // width
        keys = _bin_index(ref_pixels, width)
        medians, counts = _group_medians(keys, offsets, n**3)
        enclosing = fine * finest // width
        parent = (enclosing[:, 0] * n + enclosing[:, 1]) * n + enclosing[:, 2]
        has_own = counts[parent] >= (min_count if width < 256 else 1)
        lut[has_own] = medians[parent[has_own]]
    return lut.reshape(n_fine, n_fine, n_fine, 3)


def _group_medians(
    keys: np.ndarray, values: np.ndarray, groups: int
) -> tuple[np.ndarray, np.ndarray]:
    # Per-group median of each column: sort by (key, value), then each group's middle rows.
    counts = np.bincount(keys, minlength=groups)
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    present = np.flatnonzero(counts)
    low = starts[present] + (counts[present] - 1) // 2
    high = starts[present] + counts[present] // 2
    medians = np.zeros((groups, values.shape[1]), np.float32)
    for channel in range(values.shape[1]):
        order = np.lexsort((values[:, channel], keys))
        ordered = values[order, channel]
        medians[present, channel] = 0.5 * (ordered[low] + ordered[high])
    return medians, counts
