"""The geometry of warping a rendered view to a nearby one: the cameras' relative motion,
image corners under a homography, how far content moves and how much of an image a render
with a margin covers. Pure NumPy/OpenCV; :mod:`.reuse` decides with it."""

from __future__ import annotations

import math

import cv2
import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics


def widened(camera: CameraIntrinsics, margin: int) -> CameraIntrinsics:
    """``camera`` with ``margin`` more pixels on every side (same focal length)."""
    return CameraIntrinsics(
        width=camera.width + 2 * margin,
        height=camera.height + 2 * margin,
        fx=camera.fx,
        fy=camera.fy,
        cx=camera.cx + margin,
        cy=camera.cy + margin,
    )


def relative_motion(T_station_from: np.ndarray, T_station_to: np.ndarray) -> np.ndarray:
    """4x4 transform taking points of the ``from`` camera frame into the ``to`` camera's."""
    rotation_to = T_station_to[:3, :3]
    motion = np.eye(4)
    motion[:3, :3] = rotation_to.T @ T_station_from[:3, :3]
    motion[:3, 3] = rotation_to.T @ (T_station_from[:3, 3] - T_station_to[:3, 3])
    return motion


def depth_in_view(depth: np.ndarray, motion: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """The z depth of each pixel of ``camera``'s ``depth`` image measured in another camera
    (``motion`` takes points of ``camera``'s frame into that camera's), at the same pixel;
    0 (nothing hit) stays 0.

    A point at pixel ``p`` and depth ``z`` is ``z K^-1 p``, so its new depth is
    ``z (R_3 . K^-1 p) + t_3``: the warp moves the pixel, this keeps the value metric.
    """
    height, width = depth.shape
    inverse = np.linalg.inv(camera.matrix)
    # R_3 . K^-1 [u, v, 1] is affine in u and v: one row times the pixel coordinates.
    row = motion[2, :3] @ inverse
    cols = (row[0] * np.arange(width)).astype(np.float32)
    rows = (row[1] * np.arange(height) + row[2]).astype(np.float32)
    moved = depth * (rows[:, None] + cols[None, :]) + np.float32(motion[2, 3])
    return np.where(depth > 0, moved, np.float32(0.0)).astype(np.float32, copy=False)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two vectors in degrees (0 for two zero vectors)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    norms = np.linalg.norm(a) * np.linalg.norm(b)
    if norms == 0:
        return 0.0 if np.linalg.norm(a) == np.linalg.norm(b) else 180.0
    # atan2 of the cross and dot products is accurate for tiny angles (arccos is not).
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(a, b))), float(a @ b)))


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """The angle of a 3x3 rotation in degrees, from its axis-angle vector (accurate near 0)."""
    vector, _ = cv2.Rodrigues(rotation)
    return math.degrees(float(np.linalg.norm(vector)))


def image_corners(camera: CameraIntrinsics) -> np.ndarray:
    """(4, 2) outer corners of ``camera``'s image (pixel centres at integers)."""
    w, h = camera.width - 0.5, camera.height - 0.5
    return np.array([[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h]])


def apply_homography(homography: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) ``points`` mapped through the 3x3 ``homography``."""
    mapped = np.c_[points, np.ones(len(points))] @ homography.T
    return mapped[:, :2] / mapped[:, 2:3]


def uncovered_px(homography: np.ndarray, camera: CameraIntrinsics, wide: CameraIntrinsics) -> float:
    """How far (keyframe pixels) the view's image reaches beyond the keyframe's render."""
    return beyond_px(apply_homography(np.linalg.inv(homography), image_corners(camera)), wide)


def beyond_px(points: np.ndarray, camera: CameraIntrinsics) -> float:
    """How far the farthest of ``points`` lies outside ``camera``'s image (0: inside)."""
    low = -0.5 - points
    high = points - np.array([camera.width - 0.5, camera.height - 0.5])
    return float(max(0.0, low.max(), high.max()))


def content_offset_px(shown: np.ndarray, wanted: np.ndarray, camera: CameraIntrinsics) -> float:
    """How far (keyframe pixels) the content of an image warped with ``shown`` lies from
    where the warp ``wanted`` puts it, at the image's corners."""
    corners = image_corners(camera)
    difference = apply_homography(np.linalg.inv(shown), corners) - apply_homography(
        np.linalg.inv(wanted), corners
    )
    return float(np.linalg.norm(difference, axis=1).max())


def largest_shift_px(homography: np.ndarray, camera: CameraIntrinsics, margin: int) -> float:
    """How far the warp moves the image's corners from where the plain crop puts them."""
    crop = np.array([[1.0, 0.0, -margin], [0.0, 1.0, -margin], [0.0, 0.0, 1.0]])
    corners = image_corners(camera) + margin
    return float(
        np.abs(apply_homography(homography, corners) - apply_homography(crop, corners)).max()
    )
