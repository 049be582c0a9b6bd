"""Stage 0'': tolerate light the reference cannot draw exactly, colourless and where it may be.

Three kinds of light brighten a query over its transferred reference without being an object,
and all add roughly the same amount to every channel:

* **A specular highlight** whose strength or width the reference does not match (another
  roughness or specular strength than the model's, a Sun of finite size). The reference is
  rendered for this view, so it already shows where a highlight falls: a surface brighter
  than its neighbourhood in its *darkest* channel (a colourless addition raises that channel
  as much as the others; a bright coloured paint does not). The reference's specular
  potential is that excess, a grey-level white top-hat of the darkest channel over a window
  of :data:`SPECULAR_WINDOW` of the image's shorter side, normalised by
  :data:`SPECULAR_FULL` levels and spread by a window of :data:`SPECULAR_SPREAD` (a sharper
  or broader lobe than the reference's covers more or less of the surface round the
  reference's highlight). Only the reference's pixels enter: the potential is computed once
  per reused reference (:mod:`~allo_mrad_ros.detector.reference_cache`).
* **A glare halo** round clipped query pixels (a lens's flare, a sensor's bloom), which
  reaches further the larger the clipped region: each connected clipped component of area
  ``A`` (pixels at the processing resolution) whose pixels the reference shows lit gets a
  halo of radius ``glare_halo * sqrt(A)``. A clipped component over a surface the reference
  does not light (a bright object, the Sun over space) makes none, and the clipped pixels
  themselves are left to the colour transfer's glare rule (``glare_level``).
* **The Sun's glare**: with the Sun in view, the camera clips its disc and its optics
  spread it (bloom, a starburst, a halo) far beyond the disc the reference draws. The Sun's
  position in the image is known from the view, so the clipped component at that position
  is the Sun and not a glint off an object: it and every pixel within
  ``sun_glare * sqrt(A)`` of it (``A`` its area) are tolerated.

Where any applies, the query's *colourless* brightening over the reference pixel, the
smallest of its three channel excesses (zero when any channel is not brighter), is
subtracted from all three channels, up to an allowance: ``specular_tolerance`` 8-bit levels
times the specular potential (rounded to whole levels), and without limit inside a halo or
the Sun's glare. A coloured object there keeps its colour departure; a dark one is not
brighter and keeps all of it; a colourless highlight where no highlight is predicted and no
clipped region is near keeps all of it.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from allo_mrad_ros.detector.images import brightest_channel, eight_bit, reference_at
from allo_mrad_ros.detector.reference_cache import ReferenceCache, derived
from allo_mrad_ros.errors import InvalidInput

__all__ = [
    "CLIPPED_LEVEL",
    "LIT_LEVEL",
    "SPECULAR_FULL",
    "SPECULAR_SPREAD",
    "SPECULAR_WINDOW",
    "SUN_GLARE_MAX_RADIUS",
    "SUN_REACH",
    "SUN_WHITE_MARGIN",
    "UNLIMITED",
    "HighlightsError",
    "allowance",
    "colourless_excess",
    "glare_halo",
    "specular_potential",
    "sun_glare",
    "sun_reach",
    "tolerate_highlights",
]

# The three constants of the potential were chosen on the path-traced bench's validation
# split (docs/evaluation.md); the test split was not consulted.
SPECULAR_WINDOW = 1.0 / 8.0
"""The top-hat's window (what narrower than it is a highlight), as a fraction of the image's
shorter side."""
SPECULAR_SPREAD = 1.0 / 16.0
"""The spread's window, as a fraction of the image's shorter side."""
SPECULAR_FULL = 32.0
"""A darkest-channel excess of this many 8-bit levels over the neighbourhood is a full
highlight (potential 1)."""
CLIPPED_LEVEL = 250
"""A query pixel with a channel at or above this level (8-bit scale) is clipped."""
LIT_LEVEL = 128.0
"""Mean brightest reference channel over a clipped component from which it is glare."""
UNLIMITED = 255
"""The allowance inside a glare halo: any colourless brightening."""
SUN_GLARE_MAX_RADIUS = 1.0 / 4.0
"""The Sun's glare reaches at most this fraction of the image's shorter side from its clipped
region: a Sun clipped together with a lit surface next to it makes one large component, whose
area says nothing of the glare. (On the validation sequences the rule's radius reached 23 %
at most.)"""
SUN_REACH = 1.0 / 64.0
"""How far a clipped component may lie from the Sun's computed position and be the Sun, as a
fraction of the image's shorter side (see :func:`sun_reach`)."""
SUN_WHITE_MARGIN = 255 - CLIPPED_LEVEL
"""Where the Sun's brightest pixel lies below :data:`CLIPPED_LEVEL` (a tone curve or view
transform whose white is under 255: a filmic curve's shoulder, AgX), the Sun's disc is the
pixels within this many levels of it, as 250 is of 255."""


class HighlightsError(InvalidInput):
    """The highlight tolerance cannot run with these inputs or parameters."""


def _window(shape: tuple[int, int]) -> int:
    # Odd, at least 3: a symmetric square neighbourhood.
    side = max(3, round(min(shape) * SPECULAR_WINDOW))
    return side | 1


def specular_potential(reference: np.ndarray) -> np.ndarray:
    """H x W float32 in [0, 1]: where, in this view, the reference predicts a highlight.

    Parameters
    ----------
    reference : numpy.ndarray
        uint8 H x W x 3, the reference at the processing resolution.
    """
    darkest = _darkest(reference)
    side = _window(darkest.shape)
    kernel = np.ones((side, side), np.uint8)
    # The white top-hat: the darkest channel over its opening (what is left of it once
    # every bright feature narrower than the window is removed).
    excess = cv2.morphologyEx(darkest, cv2.MORPH_TOPHAT, kernel, borderType=cv2.BORDER_REPLICATE)
    # A sharper or broader lobe than the reference's covers more or less of the surface
    # round the reference's highlight. Spread before the scaling, in uint8: a maximum
    # commutes with the monotone scaling and capping, and is cheaper on bytes.
    spread = max(1, round(min(darkest.shape) * SPECULAR_SPREAD)) | 1
    if spread > 1:
        square = np.ones((spread, spread), np.uint8)
        excess = cv2.dilate(excess, square, borderType=cv2.BORDER_REPLICATE)
    return np.minimum(excess.astype(np.float32) * np.float32(1.0 / SPECULAR_FULL), 1.0)


def glare_halo(query: np.ndarray, reference: np.ndarray, factor: float) -> np.ndarray:
    """H x W bool: the halos round the clipped components of ``query`` that the reference
    predicts lit (their pixels themselves excluded).

    Parameters
    ----------
    query : numpy.ndarray
        uint8 H x W x 3, the query at the processing resolution before the colour transfer.
    reference : numpy.ndarray
        uint8 H x W x 3, the reference at the query's size: a clipped component counts when
        the reference's brightest channel averages at least :data:`LIT_LEVEL` over it (a
        lit surface the camera clipped; a clipped object the reference lacks makes none).
    factor : float
        A component of area ``A`` reaches every pixel within Euclidean distance
        ``factor * sqrt(A)`` of one of its pixels; 0 gives no halo.
    """
    halo = np.zeros(query.shape[:2], bool)
    if factor <= 0.0:
        return halo
    count, labels, stats = _clipped_components(_brightest(query))
    if count <= 1:
        return halo
    clipped = labels > 0
    lit = brightest_channel(reference)
    sums = np.bincount(labels.ravel(), weights=lit.ravel(), minlength=count)
    for label in range(1, count):
        area = stats[label, cv2.CC_STAT_AREA]
        if sums[label] >= LIT_LEVEL * area:
            _add_halo(halo, labels, stats, label, factor * math.sqrt(area))
    # The clipped pixels themselves are not tolerated here: over station the colour
    # transfer's glare rule already takes them; over space they may be a bright object.
    return halo & ~clipped


def _clipped_components(
    brightest: np.ndarray, level: int = CLIPPED_LEVEL
) -> tuple[int, np.ndarray, np.ndarray]:
    """The 8-connected components of the clipped pixels (``brightest``, each pixel's largest
    channel, at or above ``level``): their count (the background included), labels and
    stats."""
    clipped = (brightest >= level).astype(np.uint8)
    if not cv2.countNonZero(clipped):
        return 1, np.zeros(clipped.shape, np.int32), np.zeros((1, 5), np.int32)
    return cv2.connectedComponentsWithStats(clipped, connectivity=8)[:3]


def _add_halo(
    halo: np.ndarray, labels: np.ndarray, stats: np.ndarray, label: int, radius: float
) -> None:
    """Mark in ``halo`` every pixel within ``radius`` of component ``label``, the
    component's own pixels included."""
    height, width = halo.shape
    x, y, w, h, _ = (int(v) for v in stats[label])
    reach = math.floor(radius)
    top, bottom = max(0, y - reach), min(height, y + h + reach)
    left, right = max(0, x - reach), min(width, x + w + reach)
    outside = (labels[top:bottom, left:right] != label).astype(np.uint8)
    # Exact Euclidean distance to the component's nearest pixel (0 on it).
    distance = cv2.distanceTransform(outside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    halo[top:bottom, left:right] |= distance <= np.float32(radius)


def sun_reach(shape: tuple[int, int]) -> int:
    """How far, in pixels of an image of ``shape``, a clipped component may lie from the
    Sun's computed position and still be the Sun: :data:`SUN_REACH` of the shorter side, at
    least 2 pixels (the Sun's disc and the pose's error)."""
    return max(2, round(min(shape) * SUN_REACH))


def sun_glare(
    query: np.ndarray, sun_pixel: tuple[float, float] | None, factor: float
) -> np.ndarray:
    """H x W bool: the Sun's glare, the clipped components of ``query`` at the Sun's
    position (clipped at the camera's white, :func:`_sun_white`) with every pixel within
    ``factor * sqrt(A)`` of them (``A`` their area; at most :data:`SUN_GLARE_MAX_RADIUS` of
    the image's shorter side).

    Parameters
    ----------
    query : numpy.ndarray
        uint8 H x W x 3, the query at the processing resolution before the colour transfer.
    sun_pixel : tuple of float or None
        The Sun's centre ``(x, y)`` in this image's continuous pixel coordinates (pixel
        ``(i, j)`` spans ``[i, i + 1) x [j, j + 1)``); None: no Sun in front of the camera.
        A clipped component counts when one of its pixels lies within :func:`sun_reach` of
        the pixel holding it (the Sun itself, seen through the camera's optics); a Sun out
        of the image or behind the station (nothing clipped there) makes no glare.
    factor : float
        The halo's radius per square root of the component's area; 0 gives no glare.
    """
    height, width = query.shape[:2]
    glare = np.zeros((height, width), bool)
    if factor <= 0.0 or sun_pixel is None:
        return glare
    column, row = (math.floor(v) for v in sun_pixel)
    reach = sun_reach((height, width))
    top, bottom = max(0, row - reach), min(height, row + reach + 1)
    left, right = max(0, column - reach), min(width, column + reach + 1)
    if top >= bottom or left >= right:
        return glare
    brightest = _brightest(query)
    level = _sun_white(brightest, (slice(top, bottom), slice(left, right)))
    if level is None:
        return glare
    _, labels, stats = _clipped_components(brightest, level)
    widest = SUN_GLARE_MAX_RADIUS * min(height, width)
    for label in np.unique(labels[top:bottom, left:right]):
        if label:
            radius = min(factor * math.sqrt(stats[label, cv2.CC_STAT_AREA]), widest)
            _add_halo(glare, labels, stats, int(label), radius)
    return glare


def _brightest(image: np.ndarray) -> np.ndarray:
    # Each pixel's largest channel.
    blue, green, red = cv2.split(image)
    return cv2.max(cv2.max(blue, green), red)


def _sun_white(brightest: np.ndarray, window: tuple[slice, slice]) -> int | None:
    """The level from which pixels are the Sun's clipped disc (``brightest``: each pixel's
    largest channel), given the ``window`` round the Sun's computed position; None when
    nothing there can be the Sun.

    A camera clips the Sun: its brightest pixel is the camera's white. Where that is at or
    above :data:`CLIPPED_LEVEL` the disc is the clipped pixels, as for any glare. A tone
    curve or view transform may put the camera's white lower (a filmic shoulder at 245, AgX
    near 208): then the disc is the pixels within :data:`SUN_WHITE_MARGIN` of the window's
    brightest, provided that is the frame's brightest light too (within the margin) and
    above :data:`LIT_LEVEL` (a Sun behind a module leaves only the module's light there).
    """
    core = int(brightest[window].max())
    if core >= CLIPPED_LEVEL:
        return CLIPPED_LEVEL
    if core < LIT_LEVEL or core < int(brightest.max()) - SUN_WHITE_MARGIN:
        return None
    return core - SUN_WHITE_MARGIN


def colourless_excess(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """H x W uint8: by how much every channel of ``query`` exceeds ``reference`` (uint8
    images of one size): the smallest of the three excesses, 0 where a channel is not
    brighter."""
    # A saturating subtraction clips each channel's deficit to 0, so the smallest channel
    # is max(0, min over channels of query - reference), in whole levels.
    return _darkest(cv2.subtract(query, reference))


def _darkest(image: np.ndarray) -> np.ndarray:
    # Each pixel's smallest channel (OpenCV's planes: NumPy's strided channel views of a
    # uint8 image are several times slower).
    blue, green, red = cv2.split(image)
    return cv2.min(cv2.min(blue, green), red)


def allowance(
    potential: np.ndarray | None, halo: np.ndarray | None, tolerance: float
) -> np.ndarray | None:
    """H x W uint8 levels of colourless brightening tolerated: ``tolerance`` times the
    specular ``potential`` (rounded to whole levels, half to even), and :data:`UNLIMITED`
    inside the ``halo``; None when neither."""
    allowed = None
    if potential is not None:
        allowed = cv2.convertScaleAbs(potential, alpha=float(tolerance))
    if halo is not None and halo.any():
        allowed = _unlimited_in(halo, allowed)
    return allowed


def _unlimited_in(halo: np.ndarray, allowed: np.ndarray | None) -> np.ndarray:
    # A copy: ``allowed`` may be the reference cache's read-only array.
    out = np.zeros(halo.shape, np.uint8) if allowed is None else allowed.copy()
    out[halo] = UNLIMITED
    return out


def tolerate_highlights(
    seen: np.ndarray,
    query: np.ndarray,
    reference: np.ndarray,
    *,
    specular_tolerance: float,
    glare_halo_factor: float,
    sun_glare_factor: float = 0.0,
    sun_pixel: tuple[float, float] | None = None,
    cache: ReferenceCache | None = None,
) -> np.ndarray:
    """The query with its tolerated colourless brightening over the reference removed.

    Parameters
    ----------
    seen : numpy.ndarray
        H x W x 3, the query at the processing resolution before the colour transfer (where
        clipping is read).
    query : numpy.ndarray
        H x W x 3, the processed query (after the colour transfer and any gain field).
    reference : numpy.ndarray
        The (transferred) reference of the same view, any size with the query's aspect.
    specular_tolerance : float
        8-bit levels tolerated at a full predicted highlight; 0 = none.
    glare_halo_factor : float
        The halo's radius per square root of a clipped component's area; 0 = none.
    sun_glare_factor : float
        The Sun's glare radius per square root of its clipped area (:func:`sun_glare`);
        0 = none.
    sun_pixel : tuple of float or None
        The Sun's centre in ``query``'s continuous pixel coordinates, None when it is not in
        front of the camera.
    cache : ReferenceCache, optional
        Keeps the resized reference and its specular allowance while the reference is
        reused.

    Returns
    -------
    numpy.ndarray
        uint8, the query's size; ``query`` itself when nothing is tolerated.

    Raises
    ------
    HighlightsError
        For a negative tolerance or factor, or ``seen`` of another size than ``query``.
    """
    if min(specular_tolerance, glare_halo_factor, sun_glare_factor) < 0.0:
        raise HighlightsError(
            f"specular_tolerance ({specular_tolerance}), glare_halo ({glare_halo_factor}) "
            f"and sun_glare ({sun_glare_factor}) must be >= 0"
        )
    if seen.shape[:2] != query.shape[:2]:
        raise HighlightsError(f"seen {seen.shape} and query {query.shape} differ in size")
    query = eight_bit(query)
    height, width = query.shape[:2]
    small = eight_bit(reference)
    pixels = reference_at(small, (height, width), cache)
    allowed = None
    if specular_tolerance > 0.0:
        # The reference's alone: computed once while a reference is reused.
        allowed = derived(
            cache,
            small,
            ("specular_allowance", height, width, float(specular_tolerance)),
            lambda: allowance(specular_potential(pixels), None, specular_tolerance),
        )
    if glare_halo_factor > 0.0:
        halo = glare_halo(eight_bit(seen), pixels, glare_halo_factor)
        if halo.any():
            allowed = _unlimited_in(halo, allowed)
    if sun_glare_factor > 0.0 and sun_pixel is not None:
        glare = sun_glare(eight_bit(seen), sun_pixel, sun_glare_factor)
        if glare.any():
            allowed = _unlimited_in(glare, allowed)
    if allowed is None:
        return query
    removed = cv2.min(colourless_excess(query, pixels), allowed)
    # No channel goes below the reference's: the removed amount is at most each excess.
    return cv2.subtract(query, cv2.merge((removed, removed, removed)))
