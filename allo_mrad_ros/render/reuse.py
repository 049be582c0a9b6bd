"""Reference reuse: warp the last rendered reference to a nearby view instead of rendering.

An arm camera at 30 Hz moves a few hundredths of a degree between frames, and MRAD compares
cell statistics that a pixel of misalignment does not change. So the reference is rendered
for a *keyframe* (with a margin around the image, and with its depth) and each later frame
gets the keyframe warped to its own pose:

* rotation is exact under the homography ``K R K^-1``;
* translation moves near and far surfaces differently (parallax). The warp uses the
  homography of the fronto-parallel plane at the middle of the keyframe's inverse-depth
  range, so the first-order image error of any surface is at most
  ``|t| * (1/z_near - 1/z_far) / 2 * sqrt(f^2 + r^2)`` pixels (``f`` the focal length, ``r``
  the image's half-diagonal, ``z_far`` infinite where space is in view). That bound, plus
  any part of the image the keyframe does not cover, is the warp's *error*;
* the arm's spotlight turns with the camera, so the shading of a warped keyframe drifts
  with the rotation: rotation has its own bound, and the margin is rendered wide enough for
  it.

A new keyframe is rendered when the error or the rotation bound is passed, the Sun's
direction or strength changes, the bodies in the sky move, the keyframe reaches its maximum
age, or time runs backwards (a replayed bag). A view equal to the keyframe's gets the
keyframe's own image object back, unwarped, so what the detector derived from it can be
reused (:class:`~allo_mrad_ros.detector.reference_cache.ReferenceCache`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.geometry import sphere_points
from allo_mrad_ros.render.bodies import CelestialBody
from allo_mrad_ros.render.warp import (
    angle_deg,
    apply_homography,
    beyond_px,
    content_offset_px,
    depth_in_view,
    image_corners,
    largest_shift_px,
    relative_motion,
    rotation_angle_deg,
    uncovered_px,
    widened,
)

# A warp that moves no pixel by more than this (reference pixels) is no warp: resampling
# would only blur the keyframe.
_STILL_PX = 0.02
# A warped reference stands for a later view whose pixels it shows at most this far off
# (reference pixels; the nearest-pixel warp itself rounds by up to half a pixel), so the
# detector's cache of it is used again instead of warping every frame.
_SNAP_PX = 0.25
# Resampling of the warp.
_INTERPOLATION = cv2.INTER_NEAREST
# Rotation axes sampled for the margin.
_MARGIN_AXES = 200
# Relative change of the Sun's strength that needs a new render (it scales every lit pixel).
_SUN_STRENGTH_TOLERANCE = 1e-3


class ReuseError(InvalidInput):
    """An invalid reuse bound."""


class View(Protocol):
    """What a reference is rendered from (:class:`allo_mrad_ros.view.View` has it)."""

    T_station_camera: np.ndarray
    sun_direction: np.ndarray
    sun_strength: float
    bodies: Sequence[CelestialBody]

    @property
    def sky_bodies(self) -> Sequence[CelestialBody]:
        """Every body the reference shows: :attr:`bodies` plus the Sun's disc."""


@dataclass(frozen=True)
class ReuseBounds:
    """When a rendered reference may stand for a later view.

    Parameters
    ----------
    max_error_px : float
        Largest image error the warp may make, in full-resolution camera pixels: the
        parallax bound plus any uncovered border; in [0, 256]. 0 renders every frame.
    max_rotation_deg : float
        Largest camera rotation from the keyframe (the spotlight turns with the camera), in
        [0, 20] degrees; the keyframe is rendered with a margin wide enough for it.
    max_age_s : float
        Longest a keyframe is used, in (0, 3600] seconds of the frames' own time.
    max_sun_change_deg : float
        Largest change of the Sun's direction (and of a body's) from the keyframe's, in
        [0, 10] degrees.
    """

    max_error_px: float = 2.0
    max_rotation_deg: float = 2.0
    max_age_s: float = 1.0
    max_sun_change_deg: float = 0.05

    def __post_init__(self) -> None:
        for name, low, high, low_open in (
            ("max_error_px", 0.0, 256.0, False),
            ("max_rotation_deg", 0.0, 20.0, False),
            ("max_age_s", 0.0, 3600.0, True),
            ("max_sun_change_deg", 0.0, 10.0, False),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ReuseError(f"{name} must be a number, got {value!r}")
            inside = (low < value if low_open else low <= value) and value <= high
            if not (math.isfinite(value) and inside):
                interval = f"{'(' if low_open else '['}{low:g}, {high:g}]"
                raise ReuseError(f"{name} must be in {interval}, got {value!r}")

    def margin(self, camera: CameraIntrinsics) -> int:
        """Pixels of ``camera`` rendered around the image so that a rotation of up to
        :attr:`max_rotation_deg` about any axis keeps the image covered."""
        if self.max_rotation_deg == 0:
            return 0
        # Where the image's corners come from in the keyframe after a rotation by the bound
        # about axes spread over the sphere (an off-axis corner moves more than f tan(angle)).
        inverse_k = np.linalg.inv(camera.matrix)
        reach = 0.0
        for axis in sphere_points(_MARGIN_AXES):
            rotation, _ = cv2.Rodrigues(axis * math.radians(self.max_rotation_deg))
            source = camera.matrix @ rotation.T @ inverse_k
            reach = max(reach, beyond_px(apply_homography(source, image_corners(camera)), camera))
        # One pixel for the sampled axes' gaps, one for the resampling's footprint.
        return math.ceil(reach) + 2


@dataclass(frozen=True, eq=False)
class Keyframe:
    """A rendered reference that later views may reuse.

    Attributes
    ----------
    view : View
        What it was rendered for.
    time_s : float or None
        The frame's time (None: age is not checked).
    wide : numpy.ndarray
        The render with its margin, read-only.
    image : numpy.ndarray
        The reference of :attr:`view` itself: the render without its margin, read-only.
    inverse_depth : tuple of float
        Smallest and largest inverse depth (1/m) over the render; 0 is infinitely far.
    wide_depth : numpy.ndarray or None
        The render's z depth with its margin (metres, 0 where nothing was hit), read-only.
    """

    view: View
    time_s: float | None
    wide: np.ndarray
    image: np.ndarray
    inverse_depth: tuple[float, float]
    wide_depth: np.ndarray | None = None


@dataclass(frozen=True)
class ReuseDecision:
    """Whether a view can reuse the keyframe, and how.

    Attributes
    ----------
    reason : str
        Empty when the keyframe can be reused; else why a render is needed (``first``,
        ``age``, ``clock``, ``sun``, ``bodies``, ``rotation``, ``error``, ``disabled``).
    homography : numpy.ndarray or None
        3x3 map from keyframe (wide) pixels to the view's reference pixels; None when the
        view sees what the keyframe saw (the keyframe's image is the reference).
    error_px : float
        The warp's error bound in full-resolution pixels.
    rotation_deg : float
        The camera's rotation from the keyframe.
    """

    reason: str
    homography: np.ndarray | None = None
    error_px: float = 0.0
    rotation_deg: float = 0.0

    @property
    def reuse(self) -> bool:
        """Whether the keyframe stands for the view."""
        return not self.reason


def decide(
    keyframe: Keyframe | None,
    view: View,
    time_s: float | None,
    bounds: ReuseBounds,
    camera: CameraIntrinsics,
    margin: int,
    scale: float,
) -> ReuseDecision:
    """Whether ``keyframe`` may stand for ``view`` (pure: nothing is rendered).

    Parameters
    ----------
    keyframe : Keyframe or None
        The last render (None: none yet).
    view : View
        The new frame's view.
    time_s : float or None
        The new frame's time.
    bounds : ReuseBounds
        The limits.
    camera : CameraIntrinsics
        The reference image's intrinsics (without margin).
    margin : int
        The keyframe's margin in reference pixels.
    scale : float
        Reference pixels per full-resolution pixel (to express the error in the latter).

    Returns
    -------
    ReuseDecision
    """
    if keyframe is None:
        return ReuseDecision("first")
    if bounds.max_error_px == 0:
        return ReuseDecision("disabled")
    if time_s is not None and keyframe.time_s is not None:
        if time_s < keyframe.time_s:
            return ReuseDecision("clock")
        if time_s - keyframe.time_s > bounds.max_age_s:
            return ReuseDecision("age")
    old, new = keyframe.view, view
    if (
        abs(new.sun_strength - old.sun_strength)
        > _SUN_STRENGTH_TOLERANCE * max(old.sun_strength, 1.0)
        or angle_deg(new.sun_direction, old.sun_direction) > bounds.max_sun_change_deg
    ):
        return ReuseDecision("sun")
    if not _same_bodies(old, new, bounds.max_sun_change_deg):
        return ReuseDecision("bodies")
    motion = relative_motion(old.T_station_camera, new.T_station_camera)
    rotation, translation = motion[:3, :3], motion[:3, 3]
    rotation_deg = rotation_angle_deg(rotation)
    if rotation_deg > bounds.max_rotation_deg:
        return ReuseDecision("rotation", rotation_deg=rotation_deg)
    near, far = keyframe.inverse_depth
    plane_inverse_depth = (near + far) / 2.0
    focal = max(camera.fx, camera.fy)
    half_diagonal = math.hypot(
        max(camera.cx, camera.width - camera.cx), max(camera.cy, camera.height - camera.cy)
    )
    parallax = (
        float(np.linalg.norm(translation)) * (near - far) / 2.0 * math.hypot(focal, half_diagonal)
    )
    # Keyframe pixels -> view pixels through the plane n.X = 1/plane_inverse_depth, n = z.
    plane = rotation + np.outer(translation, [0.0, 0.0, plane_inverse_depth])
    wide = widened(camera, margin)
    homography = camera.matrix @ plane @ np.linalg.inv(wide.matrix)
    homography /= homography[2, 2]
    uncovered = uncovered_px(homography, camera, wide)
    error_px = (parallax + uncovered) / scale
    if error_px > bounds.max_error_px:
        return ReuseDecision("error", error_px=error_px, rotation_deg=rotation_deg)
    if parallax < _STILL_PX and largest_shift_px(homography, camera, margin) < _STILL_PX:
        return ReuseDecision("", None, error_px, rotation_deg)
    return ReuseDecision("", homography, error_px, rotation_deg)


def warp(keyframe: Keyframe, decision: ReuseDecision, camera: CameraIntrinsics) -> np.ndarray:
    """The reference of a view that may reuse ``keyframe`` (its image itself when still)."""
    if not decision.reuse:
        raise ReuseError(f"the keyframe cannot be reused ({decision.reason})")
    if decision.homography is None:
        return keyframe.image
    return cv2.warpPerspective(
        keyframe.wide,
        decision.homography,
        (camera.width, camera.height),
        flags=_INTERPOLATION,
        borderMode=cv2.BORDER_REPLICATE,
    )


def warp_depth(
    keyframe: Keyframe,
    homography: np.ndarray | None,
    view: View,
    camera: CameraIntrinsics,
    margin: int,
) -> np.ndarray:
    """The keyframe's depth as ``view`` sees it (read-only; 0 where nothing was hit).

    Pixels move with ``homography`` (the colour's warp, None: the plain crop) and each
    depth is measured from ``view``'s camera (:func:`~.warp.depth_in_view`), so a surface
    the camera moved towards is nearer, not only shifted.
    """
    if keyframe.wide_depth is None:
        raise ReuseError("the keyframe was made without its depth")
    if homography is None:
        depth = keyframe.wide_depth[margin : margin + camera.height, margin : margin + camera.width]
        if keyframe.view is not view:
            motion = relative_motion(keyframe.view.T_station_camera, view.T_station_camera)
            depth = depth_in_view(depth, motion, camera)
        depth = np.ascontiguousarray(depth)
    else:
        motion = relative_motion(keyframe.view.T_station_camera, view.T_station_camera)
        moved = depth_in_view(keyframe.wide_depth, motion, widened(camera, margin))
        depth = cv2.warpPerspective(
            moved,
            homography,
            (camera.width, camera.height),
            flags=_INTERPOLATION,
            borderMode=cv2.BORDER_REPLICATE,
        )
    depth.flags.writeable = False
    return depth


def keyframe_of(
    view: View, time_s: float | None, wide: np.ndarray, depth: np.ndarray, margin: int
) -> Keyframe:
    """A keyframe from a render with its margin and depth (0 where nothing was hit)."""
    wide = np.ascontiguousarray(wide)
    wide.flags.writeable = False
    wide_depth = np.array(depth, dtype=np.float32)
    wide_depth.flags.writeable = False
    height, width = wide.shape[0] - 2 * margin, wide.shape[1] - 2 * margin
    image = wide[margin : margin + height, margin : margin + width]
    if margin:
        image = np.ascontiguousarray(image)
        image.flags.writeable = False
    hit = depth[depth > 0]
    # Space (nothing hit) is infinitely far: inverse depth 0.
    far = 0.0 if hit.size < depth.size else float(1.0 / hit.max())
    near = float(1.0 / hit.min()) if hit.size else 0.0
    return Keyframe(view, time_s, wide, image, (near, far), wide_depth)


class ReferenceReuse:
    """The keyframe of one camera and the decision for each new view; counts both.

    Parameters
    ----------
    camera : CameraIntrinsics
        The reference image's intrinsics (the renderer's output, without margin).
    bounds : ReuseBounds
        The limits.
    scale : float
        Reference pixels per full-resolution camera pixel.
    """

    def __init__(self, camera: CameraIntrinsics, bounds: ReuseBounds, scale: float) -> None:
        self.camera = camera
        self.bounds = bounds
        self.scale = float(scale)
        self.margin = bounds.margin(camera)
        self.wide_camera = widened(camera, self.margin)
        self.rendered = 0
        self.reused = 0
        self.last_decision = ReuseDecision("first")
        self._keyframe: Keyframe | None = None
        # The last warp: its homography and image (read-only), for the keyframe in use.
        self._warped: tuple[np.ndarray, np.ndarray] | None = None
        # What the last reference returned was: its view and the homography of its warp
        # (None: the keyframe's own image), for its depth on request.
        self._shown: tuple[View, np.ndarray | None] | None = None

    def reference(
        self,
        view: View,
        time_s: float | None,
        render: Callable[[View], tuple[np.ndarray, np.ndarray]],
    ) -> np.ndarray:
        """The reference of ``view``: the keyframe warped (or the last warp, when it shows
        the view's pixels within a quarter pixel and the bound allows), or ``render(view)``
        (the wide RGB image and its depth) made the new keyframe. Read-only."""
        decision = decide(
            self._keyframe, view, time_s, self.bounds, self.camera, self.margin, self.scale
        )
        self.last_decision = decision
        if not decision.reuse:
            rgb, depth = render(view)
            self._keyframe = keyframe_of(view, time_s, rgb, depth, self.margin)
            self._warped = None
            self._shown = (self._keyframe.view, None)
            self.rendered += 1
            return self._keyframe.image
        self.reused += 1
        if decision.homography is None:
            self._shown = (self._keyframe.view, None)
            return self._keyframe.image
        if self._warped is not None:
            homography, image = self._warped
            offset = content_offset_px(homography, decision.homography, self.camera)
            if offset < _SNAP_PX and decision.error_px + offset / self.scale <= (
                self.bounds.max_error_px
            ):
                self._shown = (view, homography)
                return image
        image = warp(self._keyframe, decision, self.camera)
        image.flags.writeable = False
        self._warped = (decision.homography, image)
        self._shown = (view, decision.homography)
        return image

    def reference_with_depth(
        self,
        view: View,
        time_s: float | None,
        render: Callable[[View], tuple[np.ndarray, np.ndarray]],
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`reference` and its z depth (metres from ``view``'s camera, 0 where
        nothing was hit), both read-only.

        The depth follows the image: the keyframe's own (cropped) where the image is the
        keyframe's, else the keyframe's depth warped with the same homography and measured
        from the new camera (:func:`warp_depth`). Only this call pays for the depth warp.
        """
        image = self.reference(view, time_s, render)
        if self._keyframe is None or self._shown is None:  # reference() sets both
            raise ReuseError("no reference has been made yet")
        shown_view, homography = self._shown
        return image, warp_depth(self._keyframe, homography, shown_view, self.camera, self.margin)


def _same_bodies(old: View, new: View, max_change_deg: float) -> bool:
    if len(old.bodies) != len(new.bodies):
        return False
    for a, b in zip(old.bodies, new.bodies, strict=True):
        if (a.name, a.resolved_colour, a.emissive) != (b.name, b.resolved_colour, b.emissive):
            return False
        distance = float(np.linalg.norm(a.centre))
        if abs(float(np.linalg.norm(b.centre)) - distance) > 1e-3 * distance:
            return False
        if abs(b.radius - a.radius) > 1e-3 * a.radius:
            return False
        if angle_deg(a.centre, b.centre) > max_change_deg:
            return False
    return True
