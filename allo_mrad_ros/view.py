"""What one reference is rendered from: the camera pose, the Sun and the bodies in the sky.

A :class:`View` is built once at the system's edge (a ROS message, a sequence row, a bag
frame) and travels whole from there to the renderer, so no stage passes loose
``(pose, sun_direction, sun_strength, bodies)`` tuples.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.render.bodies import CelestialBody
from allo_mrad_ros.sequence import Frame
from allo_mrad_ros.sky import earth_and_moon, with_sun


@dataclass(frozen=True, eq=False)
class View:
    """The camera pose and lighting of one frame (station frame).

    Parameters
    ----------
    T_station_camera : numpy.ndarray
        4x4 pose of the camera optical frame in the station frame.
    sun_direction : numpy.ndarray
        Vector towards the Sun (normalised by the renderer).
    sun_strength : float
        Relative Sun intensity, >= 0.
    bodies : tuple of CelestialBody
        The bodies given (Earth, Moon, ...); :attr:`sky_bodies` adds the Sun's disc.
    """

    T_station_camera: np.ndarray
    sun_direction: np.ndarray
    sun_strength: float = 1.0
    bodies: tuple[CelestialBody, ...] = field(default=())

    @classmethod
    def from_row(
        cls,
        T_station_camera: np.ndarray,
        sun_direction: Sequence[float],
        sun_strength: float,
        earth: Sequence[float] | None,
        moon: Sequence[float] | None,
    ) -> View:
        """The view of a sequence frame, whose Earth and Moon are ``(x, y, z, r)`` or None."""
        return cls(
            T_station_camera,
            np.array(sun_direction),
            float(sun_strength),
            earth_and_moon(earth, moon),
        )

    @classmethod
    def of_frame(cls, frame: Frame, pose: np.ndarray | None = None) -> View:
        """The view of a sequence frame; ``pose`` replaces its recorded camera pose."""
        camera = frame.T_station_camera if pose is None else pose
        return cls.from_row(
            camera, frame.sun_direction, frame.sun_strength, frame.earth, frame.moon
        )

    def sun_pixel(self, camera: CameraIntrinsics) -> tuple[float, float] | None:
        """Where the Sun's centre falls in ``camera``'s image plane.

        Parameters
        ----------
        camera : CameraIntrinsics
            The intrinsics of the image (any resolution of the camera).

        Returns
        -------
        tuple of float or None
            ``(x, y)`` in the intrinsics' continuous pixel coordinates (pixel ``(i, j)``
            spans ``[i, i + 1) x [j, j + 1)``), possibly outside the image; None when the
            Sun is not in front of the camera (or no direction is given).
        """
        direction = np.asarray(self.sun_direction, dtype=np.float64)
        return self._image_point(camera, direction)

    def body_discs(self, camera: CameraIntrinsics) -> list[tuple[float, float, float]]:
        """The discs of the bodies (Earth, Moon; not the Sun) in front of ``camera``.

        Parameters
        ----------
        camera : CameraIntrinsics
            The intrinsics of the image (any resolution of the camera).

        Returns
        -------
        list of tuple of float
            ``(x, y, radius)`` per body whose centre is in front of the camera: the centre
            in the intrinsics' continuous pixel coordinates (possibly outside the image) and
            the radius in pixels along x (a sphere's outline is a circle of that radius on the
            optical axis, slightly stretched away from it).
        """
        eye = np.asarray(self.T_station_camera, dtype=np.float64)[:3, 3]
        discs = []
        for body in self.bodies:
            if body.name.lower() == "sun":
                continue
            offset = np.asarray(body.centre, dtype=np.float64) - eye
            distance = float(np.linalg.norm(offset))
            centre = self._image_point(camera, offset)
            if centre is None or body.radius >= distance:
                continue
            radius = camera.fx * float(np.tan(np.arcsin(body.radius / distance)))
            discs.append((*centre, radius))
        return discs

    def _image_point(
        self, camera: CameraIntrinsics, direction: np.ndarray
    ) -> tuple[float, float] | None:
        """Where a direction in the station frame falls in ``camera``'s image; None when it
        does not point in front of the camera."""
        rotation = np.asarray(self.T_station_camera, dtype=np.float64)[:3, :3]
        x, y, z = rotation.T @ direction
        if not (z > 0.0 and np.isfinite([x, y, z]).all()):
            return None
        return (camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy)

    @property
    def sky_bodies(self) -> tuple[CelestialBody, ...]:
        """Every body the reference shows: :attr:`bodies` plus the Sun's disc."""
        return with_sun(self.bodies, self.sun_direction)
