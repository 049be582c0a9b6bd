"""Drawing detections for people: the camera image with a mask's outline."""

from __future__ import annotations

import cv2
import numpy as np


def outline(
    image: np.ndarray,
    mask: np.ndarray,
    colour: tuple[int, int, int],
    out: np.ndarray | None = None,
) -> np.ndarray:
    """A copy of the RGB ``image`` with the outer contours of ``mask`` drawn in ``colour``.

    The line is at least 2 px and grows with the image width, so it stays visible at 1080p.
    ``out``, a C-contiguous array of ``image``'s shape and dtype, receives the copy (a
    message's kept buffer, say); by default a new array does.
    """
    contours, _ = cv2.findContours(
        np.ascontiguousarray(mask, dtype=np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE
    )
    if out is None:
        out = np.ascontiguousarray(image).copy()
    else:
        np.copyto(out, image)
    cv2.drawContours(out, contours, -1, colour, thickness=max(2, image.shape[1] // 640))
    return out
