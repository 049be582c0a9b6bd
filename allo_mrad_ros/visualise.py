"""Drawing detections for people: the camera image with a mask's outline."""

from __future__ import annotations

import cv2
import numpy as np


def outline(image: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    """A copy of the RGB ``image`` with the outer contours of ``mask`` drawn in ``colour``.

    The line is at least 2 px and grows with the image width, so it stays visible at 1080p.
    """
    contours, _ = cv2.findContours(
        np.ascontiguousarray(mask, dtype=np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE
    )
    out = np.ascontiguousarray(image).copy()
    cv2.drawContours(out, contours, -1, colour, thickness=max(2, image.shape[1] // 640))
    return out
