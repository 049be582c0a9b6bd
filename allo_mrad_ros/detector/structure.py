"""Structure cue: edges the query has where the reference has none nearby (colour-free).

Per-cell colour statistics cannot tell a dark glossy object (a helmet visor) from the dark
or shadowed station behind it: both have the same colours. What sets the object apart is
its outline and its specular highlights, which are *structure*: local contrast that the
reference does not have at that place.

The channel is the luminance-normalised gradient, ``|grad log(Y + DARK_FLOOR)|`` (``Y`` the
BT.601 luma on the 0..255 scale, Sobel 3 x 3 over 8: the change of log luminance per
pixel). Normalising by luminance makes a 20 % panel seam weigh the same on a bright and a
dark panel, so an edge between two dark surfaces is not drowned by the seams of bright
ones; the floor keeps sensor noise in black areas from looking like contrast.

The query's channel is compared with the reference's *near the same place*: the excess
``d = e_q - max_near(e_r)`` over the largest reference value within ``NEAR`` pixels (a
dilation, which absorbs the pose error of a few pixels at the working resolution), so an
outline the reference has nowhere nearby scores even in a cell full of station edges
elsewhere. Per grid cell, what the query's noise and texture give everywhere is set aside
robustly: the score is the excess over the cell's median of ``d`` plus ``NOISE_SIGMAS``
times its MAD-based spread::

    s(x) = max(0, d(x) - max(0, median_cell(d) + NOISE_SIGMAS * 1.4826 * MAD_cell(d)))

(never below the reference's own nearby structure: identical images score 0).

Both images are brought to the coarser of the two resolutions first (gradients are per
pixel), and the score is resized to the query's size.
"""

from __future__ import annotations

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_slices
from allo_mrad_ros.detector.images import area_downscale

DARK_FLOOR = 8.0
"""Luminance (8-bit levels) added before the log: below it, contrast is mostly noise."""

NEAR = 2
"""Pixels (at the coarser resolution) within which a reference edge explains a query edge."""

NOISE_SIGMAS = 3.0
"""Robust standard deviations of a cell's excess that noise and texture may reach."""

_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


def luminance(image: np.ndarray) -> np.ndarray:
    """BT.601 luma of an H x W x 3 image, float32 on the 0..255 scale.

    Parameters
    ----------
    image : numpy.ndarray
        uint8 (0..255), uint16 (0..65535) or float (0..1) colour image.

    Returns
    -------
    numpy.ndarray
        H x W float32.
    """
    if image.dtype == np.uint8:
        scale = 1.0
    elif image.dtype == np.uint16:
        scale = 255.0 / 65535.0
    else:
        scale = 255.0
    weights = (_LUMA * np.float32(scale)).reshape(1, 3)
    # A one-row matrix gives a one-channel result, which OpenCV returns as H x W.
    return cv2.transform(image.astype(np.float32), weights).reshape(image.shape[:2])


def structure_channel(luma: np.ndarray) -> np.ndarray:
    """The luminance-normalised gradient magnitude ``|grad log(luma + DARK_FLOOR)|``.

    Sobel 3 x 3 derivatives divided by 8 (a unit step per pixel gives 1), OpenCV's default
    border (reflect-101).

    Returns
    -------
    numpy.ndarray
        H x W float32, >= 0.
    """
    log_luma = np.log(luma + np.float32(DARK_FLOOR))
    gx = cv2.Sobel(log_luma, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(log_luma, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    return cv2.magnitude(gx, gy)


def structure_score(query: np.ndarray, reference: np.ndarray, grid: int) -> np.ndarray:
    """Per-pixel structure excess of the query over its reference cell (see module).

    Parameters
    ----------
    query, reference : numpy.ndarray
        Validated H x W x 3 images of the same aspect ratio (any resolutions).
    grid : int
        Cells per side, as the cross score's.

    Returns
    -------
    numpy.ndarray
        Query-sized float32 map, >= 0 and finite; 0 where the query has no more structure
        than the reference near the same place (everywhere for identical images).
    """
    height, width = query.shape[:2]
    q_luma, r_luma = luminance(query), luminance(reference)
    # Gradients are per pixel, so both channels are taken at the coarser resolution.
    if r_luma.shape[1] < width:
        q_luma = area_downscale(q_luma, (r_luma.shape[1], r_luma.shape[0]))
    elif r_luma.shape[1] > width:
        r_luma = area_downscale(r_luma, (width, height))
    q_edges, r_edges = structure_channel(q_luma), structure_channel(r_luma)
    window = np.ones((2 * NEAR + 1, 2 * NEAR + 1), np.uint8)
    if r_edges.shape != q_edges.shape:  # a one-pixel aspect difference
        r_edges = cv2.resize(r_edges, q_edges.shape[::-1], interpolation=cv2.INTER_LINEAR)
    excess = q_edges - cv2.dilate(r_edges, window)
    score = np.zeros_like(excess)
    for cell in cell_slices(*excess.shape, grid):
        values = excess[cell]
        centre = np.median(values)
        spread = 1.4826 * np.median(np.abs(values - centre))
        level = np.float32(max(0.0, centre + NOISE_SIGMAS * spread))
        np.maximum(values - level, 0.0, out=score[cell])
    if score.shape != (height, width):
        score = cv2.resize(score, (width, height), interpolation=cv2.INTER_LINEAR)
    return score
