"""One camera frame in, detections out: render the reference at the pose, then detect.

The ROS node and ``allo-bag evaluate`` both call :meth:`FrameProcessor.process`, so what is
measured offline is what runs online.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from allo_mrad_ros.detector import METHODS, DetectionResult, MradParams
from allo_mrad_ros.ephemeris import SUN_DISTANCE_M, SUN_RADIUS_KM
from allo_mrad_ros.render import CelestialBody, ReferenceRenderer

# Mean apparent radius of the Sun from the Earth-Moon system (1 au): 0.2665 degrees.
SUN_ANGULAR_RADIUS_RAD = math.asin(SUN_RADIUS_KM / 149_597_870.7)


class ProcessingError(ValueError):
    """A frame cannot be processed (image size, method name, ...)."""


@dataclass(frozen=True)
class ProcessedFrame:
    """The reference used and each method's detection for one frame.

    Attributes
    ----------
    reference : numpy.ndarray
        The reference RGB image (rendered at the renderer's output scale, or supplied).
    results : dict
        Method name to :class:`~allo_mrad_ros.detector.DetectionResult`, in the order asked.
    timings_ms : dict
        ``render`` (0 when the reference was supplied), one entry per method, ``total``.
    """

    reference: np.ndarray
    results: dict[str, DetectionResult]
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def primary(self) -> DetectionResult:
        """The first method's result (MRAD for the node)."""
        return next(iter(self.results.values()))


def earth_and_moon(
    earth: Sequence[float] | None, moon: Sequence[float] | None
) -> tuple[CelestialBody, ...]:
    """Celestial bodies from a sequence frame's ``(x, y, z, r)`` Earth and Moon, where given."""
    return tuple(
        CelestialBody(name, tuple(float(v) for v in value[:3]), float(value[3]))
        for name, value in (("earth", earth), ("moon", moon))
        if value is not None
    )


def with_sun(
    bodies: Sequence[CelestialBody | Sequence], sun_direction: Sequence[float]
) -> list[CelestialBody | Sequence]:
    """``bodies`` plus the Sun's disc along ``sun_direction``, unless a ``sun`` is there."""
    bodies = list(bodies)
    names = {b.name if isinstance(b, CelestialBody) else b[0] for b in bodies}
    if "sun" in names:
        return bodies
    direction = np.asarray(sun_direction, dtype=np.float64)
    norm = float(np.linalg.norm(direction))
    if not np.isfinite(norm) or norm == 0.0:
        return bodies  # the renderer reports the invalid direction itself
    centre = tuple(SUN_DISTANCE_M * direction / norm)
    radius = SUN_DISTANCE_M * math.tan(SUN_ANGULAR_RADIUS_RAD)
    return [*bodies, CelestialBody("sun", centre, radius)]


class FrameProcessor:
    """Render-then-detect for a stream of frames from one camera.

    Parameters
    ----------
    renderer : ReferenceRenderer
        Built once for the camera's intrinsics and the reference scale; reused per frame.
    params : MradParams, optional
        Detector parameters (defaults if omitted).
    methods : sequence of str
        Detectors to run, names from :data:`allo_mrad_ros.detector.METHODS`.
    """

    def __init__(
        self,
        renderer: ReferenceRenderer,
        params: MradParams | None = None,
        methods: Sequence[str] = ("MRAD",),
    ) -> None:
        unknown = [name for name in methods if name not in METHODS]
        if unknown or not methods:
            raise ProcessingError(
                f"unknown detection method(s) {unknown or list(methods)}; "
                f"choose from {sorted(METHODS)}"
            )
        self.renderer = renderer
        self.params = params or MradParams()
        self.methods = tuple(methods)

    def render_reference(
        self,
        T_station_camera: np.ndarray,
        sun_direction: Sequence[float],
        sun_strength: float = 1.0,
        bodies: Sequence[CelestialBody | Sequence] = (),
    ) -> np.ndarray:
        """The reference RGB image for a camera pose and lighting.

        The Sun's disc is in the camera image whenever the Sun is in view, so unless
        ``bodies`` already has a ``sun``, one is added along ``sun_direction`` with its
        true apparent size (the renderer culls it when out of view, at no cost).
        """
        bodies = with_sun(bodies, sun_direction)
        return self.renderer.render(T_station_camera, sun_direction, sun_strength, bodies).rgb

    def process(
        self,
        image: np.ndarray,
        T_station_camera: np.ndarray,
        sun_direction: Sequence[float],
        sun_strength: float = 1.0,
        bodies: Sequence[CelestialBody | Sequence] = (),
        reference: np.ndarray | None = None,
    ) -> ProcessedFrame:
        """Detect anomalies in ``image`` seen from ``T_station_camera``.

        Parameters
        ----------
        image : numpy.ndarray
            H x W x 3 RGB camera image with the renderer's full-resolution size.
        T_station_camera : numpy.ndarray
            4x4 pose of the camera optical frame in the station frame.
        sun_direction, sun_strength, bodies
            Lighting and celestial bodies (see :meth:`ReferenceRenderer.render`).
        reference : numpy.ndarray, optional
            A pre-rendered reference to use instead of rendering one.

        Returns
        -------
        ProcessedFrame

        Raises
        ------
        ProcessingError
            If the image size differs from the camera's.
        ValueError
            From the detector (malformed image) or the renderer (invalid pose, lighting).
        """
        start = time.perf_counter()
        expected = (self.renderer.intrinsics.height, self.renderer.intrinsics.width)
        if getattr(image, "shape", (None, None))[:2] != expected:
            raise ProcessingError(
                f"image size {getattr(image, 'shape', None)} differs from the camera's "
                f"{expected[1]}x{expected[0]}"
            )
        timings: dict[str, float] = {"render": 0.0}
        if reference is None:
            reference = self.render_reference(T_station_camera, sun_direction, sun_strength, bodies)
            timings["render"] = 1e3 * (time.perf_counter() - start)
        results = {}
        for name in self.methods:
            method_start = time.perf_counter()
            results[name] = METHODS[name](image, reference, self.params)
            timings[name] = 1e3 * (time.perf_counter() - method_start)
        timings["total"] = 1e3 * (time.perf_counter() - start)
        return ProcessedFrame(reference, results, timings)
