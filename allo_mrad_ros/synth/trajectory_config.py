"""Settings of arm trajectories (:class:`TrajectoryConfig`), apart from the code that uses them
(:mod:`~.trajectories`), so :mod:`~.config` can hold them without importing the station model."""

from __future__ import annotations

from dataclasses import dataclass

from allo_mrad_ros.synth.validation import (
    SynthError,
    finite_number,
    integer_at_least,
    number_pair,
)

OBJECT_SCENE = "objects"
NORMAL_SCENES = ("glare", "bodies", "shadows")
SCENES = (OBJECT_SCENE, *NORMAL_SCENES)
PLACEMENTS = ("front", "space", "behind")
"""Where an object is put on a ray the path looks along: in front of the station surface the
ray meets, on a ray that meets no station (seen against space), or behind the first module
the ray meets (hidden from that view, seen from others)."""


@dataclass(frozen=True)
class TrajectoryConfig:
    """How the arm moves and what it passes.

    Parameters
    ----------
    frames : int
        Frames per trajectory (at the sequence's ``rate_hz``).
    objects : tuple of int
        Smallest and largest number of objects per ``objects`` trajectory.
    speed_m_s : tuple of float
        Range of the eye's peak speed, m/s.
    turn_deg_s : tuple of float
        Range of the view's peak turn rate, deg/s.
    drift_probability : float
        Share of objects that drift; the others are static.
    drift_m_s : tuple of float
        Range of a drifting object's speed, m/s.
    gap_s : float
        Time between the last frame of a trajectory and the first of the next.
    sun_turn_deg_s : float
        Rate at which the Sun direction turns in ``shadows`` trajectories (an orbit's
        terminator sweep, sped up so shadow edges move visibly within a few seconds).
    normal_scenes : tuple of str
        Scenes the anomaly-free trajectories cycle through.
    placements : tuple of str
        Placements the objects cycle through.
    """

    frames: int = 60
    objects: tuple[int, int] = (2, 4)
    speed_m_s: tuple[float, float] = (0.1, 0.3)
    turn_deg_s: tuple[float, float] = (1.0, 4.0)
    drift_probability: float = 0.5
    drift_m_s: tuple[float, float] = (0.01, 0.05)
    gap_s: float = 1.0
    sun_turn_deg_s: float = 1.0
    normal_scenes: tuple[str, ...] = NORMAL_SCENES
    placements: tuple[str, ...] = PLACEMENTS

    def __post_init__(self) -> None:
        integer_at_least(self.frames, "trajectory frames", 2)
        low, high = self.objects if isinstance(self.objects, tuple) else (None, None)
        integer_at_least(low, "trajectory objects (min)", 1)
        integer_at_least(high, "trajectory objects (max)", low)
        if high > 64:
            raise SynthError(f"at most 64 objects per trajectory, got {high}")
        number_pair(self.speed_m_s, "speed_m_s", 0.0)
        if self.speed_m_s[1] > 1.0:
            raise SynthError(f"speed_m_s must stay <= 1 m/s (an arm), got {self.speed_m_s}")
        number_pair(self.turn_deg_s, "turn_deg_s", 0.0)
        if self.turn_deg_s[1] > 30.0:
            raise SynthError(f"turn_deg_s must stay <= 30 deg/s, got {self.turn_deg_s}")
        finite_number(self.drift_probability, "drift_probability", 0.0, 1.0)
        number_pair(self.drift_m_s, "drift_m_s", 0.0)
        if self.drift_m_s[1] > 0.5:
            raise SynthError(f"drift_m_s must stay <= 0.5 m/s, got {self.drift_m_s}")
        finite_number(self.gap_s, "gap_s", 0.0, 3600.0)
        finite_number(self.sun_turn_deg_s, "sun_turn_deg_s", 0.0, 10.0)
        for name, values, allowed in (
            ("normal_scenes", self.normal_scenes, NORMAL_SCENES),
            ("placements", self.placements, PLACEMENTS),
        ):
            if not isinstance(values, tuple) or not values or any(v not in allowed for v in values):
                raise SynthError(f"{name} must be a non-empty tuple of {allowed}, got {values!r}")
