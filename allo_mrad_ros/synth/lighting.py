"""The light that lit the query, against the light written to ``frames.csv``.

The reference is rendered from the recorded Sun direction and strength; the real scene was
lit by a Sun a little brighter or dimmer (irradiance, the camera's unknown response) from a
direction a little off (station attitude error), with Earth-shine and an arm lamp whose
levels no model knows exactly. This is the MRAD paper's lighting variation between the
reference and the query, made on the query's side because the reference is rendered later
from the recorded values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from allo_mrad_ros.render.renderer import AMBIENT, SPOT_INTENSITY
from allo_mrad_ros.synth.realism_config import RealismConfig


@dataclass(frozen=True)
class QueryLight:
    """The Sun that lit one query.

    Attributes
    ----------
    sun_direction : numpy.ndarray
        (3,) unit vector towards the Sun, station frame.
    sun_strength : float
        Relative Sun strength.
    angle_deg : float
        Angle between this direction and the recorded one.
    """

    sun_direction: np.ndarray
    sun_strength: float
    angle_deg: float


def query_light(
    rng: np.random.Generator,
    realism: RealismConfig,
    sun_direction: np.ndarray,
    sun_strength: float,
) -> QueryLight:
    """Draw the Sun of one query around the recorded one.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws (three normals for the direction, one for the strength).
    realism : RealismConfig
        ``sun_direction_sigma_deg`` and ``sun_strength_sigma``; disabled: the recorded Sun.
    sun_direction : numpy.ndarray
        (3,) recorded direction towards the Sun (any non-zero length).
    sun_strength : float
        Recorded relative strength.

    Returns
    -------
    QueryLight
    """
    recorded = np.asarray(sun_direction, dtype=np.float64)
    recorded = recorded / np.linalg.norm(recorded)
    if not realism.enabled:
        return QueryLight(recorded, float(sun_strength), 0.0)
    # A small rotation about a random axis: per-axis normal angles (the rotation vector).
    rotation_vector = rng.normal(0.0, math.radians(realism.sun_direction_sigma_deg), 3)
    angle = float(np.linalg.norm(rotation_vector))
    direction = recorded
    if angle > 0:
        axis = rotation_vector / angle
        direction = (
            recorded * math.cos(angle)
            + np.cross(axis, recorded) * math.sin(angle)
            + axis * float(axis @ recorded) * (1.0 - math.cos(angle))
        )
    strength = float(sun_strength) * math.exp(rng.normal(0.0, realism.sun_strength_sigma))
    between = math.degrees(math.acos(float(np.clip(direction @ recorded, -1.0, 1.0))))
    return QueryLight(direction / np.linalg.norm(direction), strength, between)


def query_lamps(rng: np.random.Generator, realism: RealismConfig) -> tuple[float, float]:
    """Ambient and spot-lamp levels of the query renderer, once per sequence.

    Returns
    -------
    ambient, spot_intensity : float
        The reference renderer's defaults scaled by draws from ``ambient_gain`` and
        ``spot_gain`` (the defaults themselves when realism is off).
    """
    if not realism.enabled:
        return AMBIENT, SPOT_INTENSITY
    return (
        AMBIENT * float(rng.uniform(*realism.ambient_gain)),
        SPOT_INTENSITY * float(rng.uniform(*realism.spot_gain)),
    )
