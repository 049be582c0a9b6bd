"""The render benchmark's scene, shared with the render tests: ALLO's Sun, Earth and Moon of
one day and twelve arm-camera-like viewpoints of the station."""

from __future__ import annotations

import numpy as np

from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import CelestialBody

# ALLO's ephemeris table, day 5 (Blender units = metres, scaled with apparent size kept).
SUN_CENTRE = (713.4, -3611.3, -1565.0)
BODIES = (
    CelestialBody("sun", SUN_CENTRE, 18.97),
    CelestialBody("earth", (1069.0, 1517.1, 745.3), 35.28),
    CelestialBody("moon", (0.0, -411.5, -284.0), 212.3),
)


def viewpoints() -> list[np.ndarray]:
    """Twelve arm-camera-like poses: 8 to 40 m from the station, looking at its parts."""
    targets = [(-6.0, 0.0, 0.0), (0.0, 0.0, 0.0), (7.5, 0.0, 0.0), (13.0, 0.0, 1.0)]
    poses = []
    for i in range(12):
        azimuth = 2.0 * np.pi * i / 12.0
        distance = 8.0 + 32.0 * ((i * 5) % 12) / 11.0
        elevation = np.radians(-30.0 + 60.0 * ((i * 7) % 12) / 11.0)
        target = np.array(targets[i % len(targets)])
        offset = distance * np.array(
            [
                np.cos(elevation) * np.cos(azimuth),
                np.cos(elevation) * np.sin(azimuth),
                np.sin(elevation),
            ]
        )
        poses.append(look_at(target + offset, target))
    return poses
