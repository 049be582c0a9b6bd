"""Pinhole camera intrinsics (the values of a ``sensor_msgs/CameraInfo`` without distortion)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels.

    Parameters
    ----------
    width, height : int
        Image size in pixels, both positive.
    fx, fy : float
        Focal lengths in pixels, positive and finite.
    cx, cy : float
        Principal point in pixels, finite.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value <= 0:
                raise ValueError(f"camera {name} must be a positive integer, got {value!r}")
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"camera {name} must be positive and finite, got {value!r}")
        for name in ("cx", "cy"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"camera {name} must be finite, got {value!r}")

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K (float64)."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    def scaled(self, scale: float) -> CameraIntrinsics:
        """Return the intrinsics of the same camera at a different output resolution.

        The image size is rounded to whole pixels (at least one) and the focal lengths and
        principal point follow the actual size ratio per axis, so the field of view and the
        pixel-edge convention (pixel centres at integer + 0.5) are kept.

        Parameters
        ----------
        scale : float
            Linear scale factor in (0, 1] is typical; any positive finite value is accepted.

        Returns
        -------
        CameraIntrinsics
            The rescaled intrinsics.
        """
        if not math.isfinite(scale) or scale <= 0:
            raise ValueError(f"scale must be positive and finite, got {scale!r}")
        return self.resized(max(1, round(self.width * scale)), max(1, round(self.height * scale)))

    def resized(self, width: int, height: int) -> CameraIntrinsics:
        """Return the intrinsics of this camera's image resampled to ``width`` x ``height``.

        The focal lengths and principal point follow the size ratio per axis, so the field of
        view and the pixel-edge convention (pixel centres at integer + 0.5) are kept.
        """
        sx = width / self.width
        sy = height / self.height
        return CameraIntrinsics(
            width=width,
            height=height,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
        )

    @classmethod
    def from_fov(
        cls, width: int, height: int, focal_mm: float, sensor_width_mm: float
    ) -> CameraIntrinsics:
        """Intrinsics of a Blender-style camera (square pixels, centred principal point)."""
        f = focal_mm / sensor_width_mm * width
        return cls(width=width, height=height, fx=f, fy=f, cx=width / 2.0, cy=height / 2.0)


# ALLO's Blender camera: 25 mm lens on a 36 mm sensor, 1920x1080.
ALLO_INTRINSICS = CameraIntrinsics.from_fov(1920, 1080, focal_mm=25.0, sensor_width_mm=36.0)
