"""Stage 0: colour transfer between the rendered reference and the camera's query.

A rasteriser and a camera (or a path tracer) disagree on colour in ways a per-channel gain
and offset cannot follow: a tone curve, a hue that shifts per material, black shadows where
the render shows ambient grey. Every frame pairs the reference with the query, pixel for
pixel at the smaller of the two resolutions (usually the reference's; the other image
area-averaged down to it), and learns a 3-D look-up table from reference colour to query
colour:

* the pairs near reference edges are left out (a pose error moves edges; there the pair
  holds two materials);
* the reference colours are binned on nested grids (coarsest first: the whole cube, then
  bins 64, 32, ... ``finest_bin`` levels wide per channel);
* each bin's offset ``query - reference`` is the per-channel median of its pairs, so an
  object that covers less than half of a bin's pairs does not move it; a bin with fewer than
  ``min_count`` pairs takes the offset of the finest enclosing bin that has enough.

The table is applied to either image (:data:`DIRECTIONS`): ``reference`` adds each
reference pixel's offset to it, so the reference takes the query's colours; ``query``
(:func:`apply_to_query`) replaces each query pixel by the reference colour at the same place
plus what the query departs from its predicted colour, so the query takes the reference's
colours and the reference's own cell statistics stay what they were (they can be reused
while the reference is). Glare, clipped query pixels over station surface, takes the
reference's colour in either direction.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_edges
from allo_mrad_ros.detector.images import (
    area_downscale,
    eight_bit,
    nearest_resize,
    reference_at,
    station_surface,
)
from allo_mrad_ros.detector.reference_cache import ReferenceCache, derived, read_only_cache
from allo_mrad_ros.errors import InvalidInput

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
# Pixels around clipped query pixels that count as glare too.
_GLARE_MARGIN = 2
MAX_PAIRS = 8192
"""At most this many pixel pairs enter the fit: beyond it, every k-th kept pair, k the
smallest stride that fits (medians need no more, and the fit's cost follows the count)."""
# Offsets are whole 8-bit levels in -255..255: a bin's key is bin * 512 + offset + 255.
_OFFSET_SPAN = 512


class ColourTransferError(InvalidInput):
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

    def offsets(self, reference: np.ndarray, bins: np.ndarray | None = None) -> np.ndarray:
        """Per-pixel offsets (H x W x 3 float32) of a uint8 reference image (``bins``: its
        bin indices at :attr:`bin_width`, when known)."""
        if bins is None:
            bins = _bin_index(reference, self.bin_width)
        n = 256 // self.bin_width
        # np.take is several times faster than fancy indexing for this gather.
        return np.take(self.lut.reshape(n * n * n, 3), bins, axis=0)


def fit_colour_transfer(
    query: np.ndarray,
    reference: np.ndarray,
    finest_bin: int = 16,
    min_count: int = 16,
    edge_margin: int = 0,
    cache: ReferenceCache | None = None,
) -> ColourTransfer:
    """Fit the reference-to-query colour table of one frame.

    Parameters
    ----------
    query, reference : numpy.ndarray
        Validated H x W x 3 images with the same aspect ratio (any resolutions, any accepted
        dtype); the larger is area-averaged to the smaller's size, both are taken to whole
        8-bit levels.
    finest_bin : int
        Width of the finest colour bins, one of 4, 8, 16, 32, 64.
    min_count : int
        Pairs a bin needs to have an offset of its own, >= 1.
    edge_margin : int
        Pixels around reference edges left out of the fit, 0..16.
    cache : ReferenceCache, optional
        Where the reference's samples and bins are kept while it is reused.

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
    samples = derived(
        cache,
        reference8,
        ("transfer_samples", edge_margin, finest_bin, min_count),
        lambda: _reference_samples(reference8, edge_margin, finest_bin, min_count),
    )
    paired = query8.reshape(-1, 3)[samples.index]
    offsets = paired.T.astype(np.int32) - samples.pixels
    return ColourTransfer(
        lut=_nested_medians(samples, offsets, finest_bin),
        bin_width=finest_bin,
        pairs=int(samples.index.size),
    )


@dataclass(frozen=True)
class _Level:
    """How one nested grid's per-bin medians are read from a sort of the pairs' offsets."""

    base: np.ndarray  # (N,) int32 sort key before the offset: bin * _OFFSET_SPAN + 255
    low: np.ndarray  # each occupied bin's lower and upper middle position in the sorted keys
    high: np.ndarray


@dataclass(frozen=True)
class _Samples:
    """The reference side of the fit: its pairs, and where each finest bin's offset comes
    from. Depends on the reference alone, so it is kept while the reference is reused."""

    index: np.ndarray  # (N,) flat indices of the paired pixels: away from edges, strided
    pixels: np.ndarray  # (3, N) int32 reference colours of the pairs, channel first
    levels: tuple[_Level, ...]  # one per nested width, coarsest first
    # (n**3,) for each finest bin, the column of its median among all levels' occupied bins:
    # the finest enclosing bin with enough pairs.
    source: np.ndarray


def _reference_samples(
    reference: np.ndarray, edge_margin: int, finest_bin: int, min_count: int
) -> _Samples:
    keep = ~_near_edges(reference, edge_margin)
    if not keep.any():
        keep[:] = True
    index = np.flatnonzero(keep)
    index = index[:: max(1, -(-index.size // MAX_PAIRS))]
    pixels = reference.reshape(-1, 3)[index]
    source = np.zeros((256 // finest_bin) ** 3, np.intp)
    levels = []
    columns = 0
    for width in _WIDTHS[: _WIDTHS.index(finest_bin) + 1]:
        n = 256 // width
        keys = _bin_index(pixels, width)
        counts = np.bincount(keys, minlength=n**3)
        occupied = np.flatnonzero(counts)
        starts = (np.cumsum(counts) - counts)[occupied]
        levels.append(
            _Level(
                base=(keys * _OFFSET_SPAN + 255).astype(np.int32),
                low=starts + (counts[occupied] - 1) // 2,
                high=starts + counts[occupied] // 2,
            )
        )
        column = np.full(n**3, -1, np.intp)
        column[occupied] = columns + np.arange(occupied.size)
        columns += occupied.size
        parent = _enclosing_bins(finest_bin, width)
        # The one-bin level takes any pair, so every finest bin has a source.
        has_own = counts[parent] >= (min_count if width < 256 else 1)
        source[has_own] = column[parent[has_own]]
    return _Samples(index, pixels.T.astype(np.int32), tuple(levels), source)


@read_only_cache(maxsize=32)
def _enclosing_bins(finest: int, width: int) -> np.ndarray:
    # For each finest bin, the index of the bin of ``width`` that encloses it.
    n_fine, n = 256 // finest, 256 // width
    enclosing = np.indices((n_fine, n_fine, n_fine)).reshape(3, -1) * finest // width
    return (enclosing[0] * n + enclosing[1]) * n + enclosing[2]


def apply_to_reference(reference: np.ndarray, transfer: ColourTransfer) -> np.ndarray:
    """The reference in the query's colours: ``reference + offset(reference)``, uint8."""
    pixels = eight_bit(reference)
    return _to_uint8(pixels.astype(np.float32) + transfer.offsets(pixels))


def clip_glare(query: np.ndarray, reference: np.ndarray, level: float) -> np.ndarray:
    """The query with glare (see :func:`apply_to_query`) replaced by the reference's colour.

    For the ``reference`` direction, where the reference already carries the query's
    colours. Returns a uint8 image of the query's size.
    """
    values = eight_bit(query)
    pixels = nearest_resize(eight_bit(reference), values.shape[:2])
    glare = _glare(values, level) & station_surface(pixels)
    out = values.copy()
    out[glare] = pixels[glare]
    return out


def apply_to_query(
    query: np.ndarray,
    reference: np.ndarray,
    transfer: ColourTransfer,
    glare_level: float = 256.0,
    gain: np.ndarray | None = None,
    cache: ReferenceCache | None = None,
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
    glare_level : float
        A query pixel whose every channel reaches this level (8-bit scale) over station
        surface (a reference pixel that is not black) is glare: it says "brighter than
        white", not which colour, and takes the reference's colour; so does a pixel within
        two pixels of one that is brighter than its predicted colour on every channel (a
        flare's border). 256 disables it.
    gain : numpy.ndarray, optional
        (G*G, 3) per-cell, per-channel contrast gain of the query over the reference (as
        :func:`~allo_mrad_ros.detector.photometric.fit_cell_affine` fits it); 1 if omitted.
    cache : ReferenceCache, optional
        Where the reference's bins and resized colours are kept while it is reused.

    Returns
    -------
    numpy.ndarray
        uint8 image of the query's size.
    """
    height, width = query.shape[:2]
    small = eight_bit(reference)
    # The prediction r + offset(r) depends on the reference pixel alone: made at the
    # reference's size, then resized with it.
    bins = derived(
        cache,
        small,
        ("bins", transfer.bin_width),
        lambda: _bin_index(small, transfer.bin_width),
    )
    predicted = small.astype(np.float32) + transfer.offsets(small, bins)
    pixels = reference_at(small, (height, width), cache)
    predicted = nearest_resize(predicted, (height, width))
    values = eight_bit(query)
    departure = cv2.subtract(values.astype(np.float32), predicted)
    if gain is not None:
        departure = cv2.divide(departure, _per_pixel(gain, height, width))
    mapped = cv2.add(departure, pixels.astype(np.float32))
    out = _to_uint8(mapped)
    if glare_level < 256.0:
        glare = _glare(values, glare_level, departure)
        if glare.any():
            glare &= derived(
                cache, small, ("surface", height, width), lambda: station_surface(pixels)
            )
            out[glare] = pixels[glare]
    return out


def _per_pixel(cells: np.ndarray, height: int, width: int) -> np.ndarray:
    grid = round(np.sqrt(cells.shape[0]))
    rows = np.diff(cell_edges(height, grid))
    cols = np.diff(cell_edges(width, grid))
    table = cells.reshape(grid, grid, 3).astype(np.float32)
    return np.repeat(np.repeat(table, rows, axis=0), cols, axis=1)


def _glare(query: np.ndarray, level: float, departure: np.ndarray | None = None) -> np.ndarray:
    # Clipped query pixels, over station or not (the caller keeps the station's). Glare
    # bleeds past the clipped pixels (a lens's flare, a sensor's bloom): its border,
    # _GLARE_MARGIN pixels wide, goes with it where it brightened every channel.
    darkest = np.minimum(np.minimum(query[..., 0], query[..., 1]), query[..., 2])
    clipped = darkest >= level
    if not clipped.any():
        return clipped
    size = 2 * _GLARE_MARGIN + 1
    near = cv2.dilate(clipped.astype(np.uint8), np.ones((size, size), np.uint8)) > 0
    if departure is None:
        glare = near
    else:
        # Only the border's pixels need their departure read: usually a few hundred.
        border = np.flatnonzero(near & ~clipped)
        brighter = (departure.reshape(-1, 3)[border] >= 0.0).all(axis=1)
        glare = clipped.copy()
        glare.reshape(-1)[border[brighter]] = True
    return glare


def _paired(query: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    query, reference = eight_bit(query), eight_bit(reference)
    hq, wq = query.shape[:2]
    hr, wr = reference.shape[:2]
    if hq * wq > hr * wr:
        query = area_downscale(query, (wr, hr))
    elif hr * wr > hq * wq:
        reference = area_downscale(reference, (wq, hq))
    return query, reference


def _to_uint8(pixels: np.ndarray) -> np.ndarray:
    # Saturating, round-half-to-even: np.clip(np.rint(x), 0, 255) in one OpenCV call.
    return cv2.convertScaleAbs(np.maximum(pixels, 0.0, dtype=np.float32))


def _near_edges(reference: np.ndarray, margin: int) -> np.ndarray:
    kernel = np.ones((3 + 2 * margin, 3 + 2 * margin), np.uint8)
    spread = cv2.subtract(cv2.dilate(reference, kernel), cv2.erode(reference, kernel))
    widest = np.maximum(np.maximum(spread[..., 0], spread[..., 1]), spread[..., 2])
    return widest > _EDGE_LEVELS


def _bin_index(pixels: np.ndarray, width: int) -> np.ndarray:
    n = 256 // width
    shift = width.bit_length() - 1
    bins = pixels.astype(np.int32) >> shift
    return (bins[..., 0] * n + bins[..., 1]) * n + bins[..., 2]


def _nested_medians(samples: _Samples, offsets: np.ndarray, finest: int) -> np.ndarray:
    # Per bin and channel, the median of whole-level offsets: one sort per level of the
    # combined keys (bin, offset) of all three channels, then each bin's middle entries.
    # The keys fit int32, which sorts about twice as fast as int64.
    middles = []
    for level in samples.levels:
        ordered = np.sort(level.base + offsets, axis=1) & (_OFFSET_SPAN - 1)
        middles.append(ordered[:, level.low] + ordered[:, level.high])
    # Each sum is twice (median + 255).
    sums = np.concatenate(middles, axis=1)[:, samples.source]
    lut = sums.T.astype(np.float32) * np.float32(0.5) - np.float32(255.0)
    n_fine = 256 // finest
    return lut.reshape(n_fine, n_fine, n_fine, 3)
