"""Stage 0''': the limbs of the Earth and the Moon, which the reference draws too coarsely.

The reference is rendered at a fraction of the camera's resolution (1/8 by default). A
body's limb is placed there to within a reference pixel, and a small body (the Moon from
lunar distance is a few reference pixels across) is a blocky sphere of one colour, whose
phase, shading and texture at the camera's resolution it does not draw: its limb, lit or
not, departs from the query's by up to a reference pixel all round, and the contrast against
black space makes that a strong anomaly. Within ``body_margin`` reference pixels of a body's
projected limb the reference cannot say what the camera sees, so there the query takes the
reference's colour (as clipped glare over station does in the colour transfer): no departure
counts. A body whose radius is under the margin is tolerated whole; inside a larger one, and
everywhere else, the reference's body is compared as any surface is.

The discs come from the view (:meth:`~allo_mrad_ros.view.View.body_discs`): the detector
knows nothing of where the bodies are otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from allo_mrad_ros.errors import InvalidInput

__all__ = ["BodiesError", "Disc", "limb_mask", "take_reference_at_limbs"]

Disc = tuple[float, float, float]
"""A body's projected disc: centre ``x``, ``y`` in continuous pixel coordinates (pixel
``(i, j)`` spans ``[i, i + 1) x [j, j + 1)``) and radius, pixels."""


class BodiesError(InvalidInput):
    """The limb tolerance cannot run with these inputs."""


def limb_mask(shape: tuple[int, int], discs: Sequence[Disc], margin: float) -> np.ndarray:
    """H x W bool: the pixels whose centre lies within ``margin`` pixels of a disc's limb,
    inside or outside it.

    Parameters
    ----------
    shape : tuple of int
        ``(height, width)`` of the image.
    discs : sequence of Disc
        The bodies' discs in this image's pixels.
    margin : float
        Pixels; 0 gives no limb.

    Raises
    ------
    BodiesError
        For a negative margin, or a disc that is not three finite numbers with a radius >= 0.
    """
    if not margin >= 0.0:
        raise BodiesError(f"body margin must be >= 0, got {margin!r}")
    height, width = shape
    limb = np.zeros((height, width), bool)
    for disc in discs:
        if len(disc) != 3 or not np.all(np.isfinite(disc)) or disc[2] < 0:
            raise BodiesError(f"a body disc is (x, y, radius >= 0), finite: got {disc!r}")
        x, y, radius = (float(v) for v in disc)
        if margin == 0.0:
            continue
        reach = radius + margin
        # The window of pixels whose centres may lie within reach (empty when off the image).
        top, bottom = max(0, int(np.floor(y - reach))), min(height, int(np.ceil(y + reach)) + 1)
        left, right = max(0, int(np.floor(x - reach))), min(width, int(np.ceil(x + reach)) + 1)
        if top >= bottom or left >= right:
            continue
        rows = np.arange(top, bottom, dtype=np.float64)[:, None] + 0.5 - y
        cols = np.arange(left, right, dtype=np.float64)[None, :] + 0.5 - x
        distance = np.sqrt(rows * rows + cols * cols)
        limb[top:bottom, left:right] |= np.abs(distance - radius) <= margin
    return limb


def take_reference_at_limbs(
    query: np.ndarray, reference: np.ndarray, discs: Sequence[Disc], margin: float
) -> np.ndarray:
    """``query`` with the reference's colour on the bodies' limbs (:func:`limb_mask`).

    Parameters
    ----------
    query : numpy.ndarray
        H x W x 3 uint8, the processed query.
    reference : numpy.ndarray
        H x W x 3 uint8, the reference at the query's size (nearest neighbour).
    discs, margin
        As for :func:`limb_mask`, in the query's pixels.

    Returns
    -------
    numpy.ndarray
        A new array where a limb is in the image, else ``query`` itself.
    """
    if query.shape != reference.shape:
        raise BodiesError(f"query {query.shape} and reference {reference.shape} differ")
    limb = limb_mask(query.shape[:2], discs, margin)
    if not limb.any():
        return query
    out = query.copy()
    out[limb] = reference[limb]
    return out
