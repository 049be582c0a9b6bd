"""One camera frame in, detections out: render the reference of a view once, run every detector.

The node, ``allo-bag evaluate``/``ablate`` and the trade-off benchmark all build a
:class:`PipelineConfig` (render settings, :class:`~allo_mrad_ros.detector.MradParams`,
methods, array backend) and run frames through a :class:`Pipeline`, so what is measured
offline is what runs online. A :class:`Pipeline` is immutable: a change of parameters builds
a new one that shares the :class:`ReferenceProvider` (the GL context), it never mutates a
running one.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from os import PathLike
from typing import Any

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import METHODS, PROFILES, DetectionResult, MradParams, profile
from allo_mrad_ros.detector.backends import ARRAY_BACKENDS, BackendError, select_backend
from allo_mrad_ros.detector.params import PARAMETER_SPECS, ParameterSpec
from allo_mrad_ros.detector.reference_cache import ReferenceCache
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import (
    DEFAULT_SCALE,
    DEFAULT_SHADOWS,
    ReferenceRenderer,
    scaled_keeping_aspect,
)
from allo_mrad_ros.render.reuse import ReferenceReuse, ReuseBounds
from allo_mrad_ros.view import View

RENDER_BACKENDS = ("", "osmesa", "egl")
# The cheapest score map of MradParams.pixel_score, made when no one reads the map.
UNREAD_PIXEL_SCORE = "blurred"


class ProcessingError(InvalidInput):
    """A frame or a configuration cannot be processed (image size, method name, option)."""


def coerce_value(name: str, spec: ParameterSpec, value: Any) -> Any:
    """``value`` as ``spec``'s type, from text (command lines) or a number (YAML, ROS).

    An integer becomes a float for a float parameter; text is parsed as the parameter's
    type. The value is then validated against the spec.

    Raises
    ------
    ProcessingError
        Naming the parameter and the value.
    """
    if isinstance(value, str) and spec.kind in (int, float):
        try:
            value = spec.kind(value.strip())
        except ValueError:
            raise ProcessingError(
                f"{name}: {value!r} is not a valid {spec.kind.__name__}"
            ) from None
    if isinstance(value, str) and spec.kind is bool:
        text = value.strip().lower()
        if text not in ("true", "false"):
            raise ProcessingError(f"{name}: {value!r} is not true or false")
        value = text == "true"
    if spec.kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    try:
        spec.check(name, value)
    except ValueError as error:
        raise ProcessingError(str(error)) from None
    return value


def params_from(profile_name: str, changes: Mapping[str, Any] | Sequence[str] = ()) -> MradParams:
    """Detector parameters: a profile with changes, as a mapping or ``KEY=VALUE`` texts.

    Raises
    ------
    ProcessingError
        For an unknown profile or key, or a value of the wrong type or range.
    """
    if profile_name not in PROFILES:
        raise ProcessingError(f"unknown profile {profile_name!r}; choose from {sorted(PROFILES)}")
    if not isinstance(changes, Mapping):
        pairs = {}
        for text in changes:
            key, sep, value = text.partition("=")
            if not sep or key.strip() not in PARAMETER_SPECS:
                raise ProcessingError(
                    f"expected KEY=VALUE with KEY one of {sorted(PARAMETER_SPECS)}; got {text!r}"
                )
            pairs[key.strip()] = value.strip()
        changes = pairs
    unknown = sorted(set(changes) - set(PARAMETER_SPECS))
    if unknown:
        raise ProcessingError(f"unknown MRAD parameter(s) {unknown}")
    coerced = {k: coerce_value(k, PARAMETER_SPECS[k], v) for k, v in changes.items()}
    try:
        return profile(profile_name, **coerced)
    except ValueError as error:
        raise ProcessingError(str(error)) from None


@dataclass(frozen=True)
class RenderSettings:
    """How the reference is rendered.

    Parameters
    ----------
    reference_scale : float
        Linear scale of the rendered reference, (0, 1].
    shadows : bool
        Directional shadows from the Sun.
    cull_bodies : bool
        Draw celestial bodies only when in view (False exists to measure what culling saves).
    render_backend : str
        ``osmesa``, ``egl``, or empty to choose.
    reuse : ReuseBounds or None
        Warp the last rendered reference to a later view while these bounds allow
        (:mod:`allo_mrad_ros.render.reuse`); None renders every view. Frames must then
        come in their time order.
    """

    reference_scale: float = DEFAULT_SCALE
    shadows: bool = DEFAULT_SHADOWS
    cull_bodies: bool = True
    render_backend: str = ""
    reuse: ReuseBounds | None = None

    def __post_init__(self) -> None:
        scale = self.reference_scale
        if isinstance(scale, bool) or not isinstance(scale, int | float):
            raise ProcessingError(f"reference_scale must be a number, got {scale!r}")
        if not (math.isfinite(scale) and 0 < scale <= 1):
            raise ProcessingError(f"reference_scale must be in (0, 1], got {scale!r}")
        if self.render_backend not in RENDER_BACKENDS:
            raise ProcessingError(
                f"render_backend must be one of {list(RENDER_BACKENDS)}, "
                f"got {self.render_backend!r}"
            )
        if self.reuse is not None and not isinstance(self.reuse, ReuseBounds):
            raise ProcessingError(f"reuse must be ReuseBounds or None, got {self.reuse!r}")


@dataclass(frozen=True)
class PipelineConfig:
    """Everything that decides a frame's result: ``render`` (:class:`RenderSettings`),
    ``params`` (:class:`~allo_mrad_ros.detector.MradParams`; PAD and RXD use its shared
    post-processing fields) and ``methods`` (names from
    :data:`allo_mrad_ros.detector.METHODS`; the first is the primary one, MRAD for the node)
    and ``array_backend`` (where the detectors' per-pixel work runs, one of
    :data:`~allo_mrad_ros.detector.backends.ARRAY_BACKENDS`; the results do not depend on
    it beyond float32 rounding).
    """

    render: RenderSettings = field(default_factory=RenderSettings)
    params: MradParams = field(default_factory=MradParams)
    methods: tuple[str, ...] = ("MRAD",)
    array_backend: str = "numpy"

    def __post_init__(self) -> None:
        methods = tuple(self.methods)
        unknown = [name for name in methods if name not in METHODS]
        if unknown or not methods:
            raise ProcessingError(
                f"unknown detection method(s) {unknown or list(methods)}; "
                f"choose from {sorted(METHODS)}"
            )
        object.__setattr__(self, "methods", methods)
        if self.array_backend not in ARRAY_BACKENDS:
            raise ProcessingError(
                f"array_backend must be one of {list(ARRAY_BACKENDS)}, got {self.array_backend!r}"
            )

    def replace(self, **changes: Any) -> PipelineConfig:
        """A copy with ``changes`` (fields of this class or of :class:`RenderSettings`)."""
        render_fields = {f.name for f in fields(RenderSettings)}
        render_changes = {k: changes.pop(k) for k in list(changes) if k in render_fields}
        if render_changes:
            changes["render"] = replace(self.render, **render_changes)
        return replace(self, **changes)


class ReferenceProvider:
    """Renders the reference of a :class:`~allo_mrad_ros.view.View` for one camera.

    Owns the OpenGL renderer: build, use and close it on one thread. With
    ``render.reuse`` set, a view close to the last rendered one gets that render warped
    (:class:`~allo_mrad_ros.render.reuse.ReferenceReuse`); :attr:`reuse` counts both.

    Parameters
    ----------
    mesh : path-like, trimesh object or None
        Station model (None: the package's model).
    camera : CameraIntrinsics
        Full-resolution intrinsics of the camera.
    render : RenderSettings
        Scale, shadows, body culling, backend, reuse bounds.
    """

    def __init__(
        self,
        mesh: str | PathLike[str] | Any | None,
        camera: CameraIntrinsics,
        render: RenderSettings,
    ) -> None:
        self.settings = render
        self._camera = camera
        # The renderer's own rule: the reference keeps the image's aspect ratio.
        self.reference_camera = scaled_keeping_aspect(camera, render.reference_scale)
        self.reuse: ReferenceReuse | None = None
        render_camera, scale = camera, render.reference_scale
        if render.reuse is not None:
            self.reuse = ReferenceReuse(
                self.reference_camera, render.reuse, self.reference_camera.width / camera.width
            )
            # The keyframe is rendered at the reference's own size plus the reuse margin.
            render_camera, scale = self.reuse.wide_camera, 1.0
        self.renderer = ReferenceRenderer(
            mesh,
            render_camera,
            scale=scale,
            backend=render.render_backend or None,
            shadows=render.shadows,
            cull_bodies=render.cull_bodies,
        )

    @property
    def camera(self) -> CameraIntrinsics:
        """Full-resolution intrinsics the references are rendered for."""
        return self._camera

    def render(self, view: View, time_s: float | None = None) -> np.ndarray:
        """The reference RGB image of ``view``, the Sun's disc included.

        ``time_s`` is the frame's time (its stamp), which limits how long a render is
        reused; None leaves age unchecked. With reuse the array is read-only (it may be the
        last render's own).
        """
        if self.reuse is None:
            return self._render(view)[0]
        return self.reuse.reference(view, time_s, self._render)

    def _render(self, view: View) -> tuple[np.ndarray, np.ndarray]:
        result = self.renderer.render(
            view.T_station_camera,
            view.sun_direction,
            view.sun_strength,
            view.sky_bodies,
            depth=self.reuse is not None,
        )
        return result.rgb, result.depth

    def warm_up(self) -> None:
        """Render once from a pose looking at the station, outside any reuse: the first
        render compiles the shaders and fills the GL caches (several times a frame's time)."""
        low, high = self.renderer.station_bounds
        centre = (low + high) / 2.0
        eye = centre + np.array([0.0, -1.0, 0.3]) * 2.0 * float(np.linalg.norm(high - low))
        self.renderer.render(look_at(eye, centre), (0.3, -0.5, 0.8))

    def close(self) -> None:
        """Release the GL context."""
        self.renderer.close()


@dataclass(frozen=True)
class ProcessedFrame:
    """The reference used and each method's detection for one frame.

    Attributes
    ----------
    reference : numpy.ndarray
        The reference RGB image (rendered at the reference scale, or supplied).
    results : dict
        Method name to :class:`~allo_mrad_ros.detector.DetectionResult`, in the order asked.
    timings_ms : dict
        ``render`` (0 when the reference was supplied), one entry per method, ``total``.
    reference_camera : CameraIntrinsics or None
        The intrinsics the reference was rendered with (None when it was supplied).
    """

    reference: np.ndarray
    results: dict[str, DetectionResult]
    timings_ms: dict[str, float] = field(default_factory=dict)
    reference_camera: CameraIntrinsics | None = None

    @property
    def primary(self) -> DetectionResult:
        """The first method's result (MRAD for the node)."""
        return next(iter(self.results.values()))


class Pipeline:
    """Render-then-detect for a stream of frames from one camera: render once, detect many.

    Parameters
    ----------
    provider : ReferenceProvider
        Renders the references; shared by pipelines built with :meth:`with_config`.
    config : PipelineConfig
        Parameters and methods (its render settings are the provider's).
    """

    def __init__(
        self,
        provider: ReferenceProvider,
        config: PipelineConfig | None = None,
        cache: ReferenceCache | None = None,
    ) -> None:
        config = config or PipelineConfig(render=provider.settings)
        if config.render != provider.settings:
            raise ProcessingError(
                f"render settings {config.render} differ from the provider's {provider.settings}"
            )
        self._provider = provider
        self._config = config
        # What the methods derive from a reused reference alone; shared with the pipelines
        # with_config makes (its keys hold every parameter a value depends on).
        self._cache = cache or ReferenceCache()
        try:
            self._backend = select_backend(config.array_backend)
        except BackendError as error:
            raise ProcessingError(str(error)) from None
        # What the methods run with when no one reads the score map (see detect()). The
        # map_top image score is taken from the map, so then the map is made anyway.
        params = config.params
        map_needed = params.image_score == "map_top"
        self._params_without_map = (
            params
            if map_needed or params.pixel_score == UNREAD_PIXEL_SCORE
            else params.replace(pixel_score=UNREAD_PIXEL_SCORE)
        )

    @property
    def provider(self) -> ReferenceProvider:
        """The reference provider."""
        return self._provider

    @property
    def config(self) -> PipelineConfig:
        """The configuration (immutable)."""
        return self._config

    def with_config(self, config: PipelineConfig) -> Pipeline:
        """A pipeline with another configuration sharing this one's provider."""
        return Pipeline(self._provider, config, self._cache)

    def warm_up(self) -> None:
        """Render once and run every method on a blank frame, so the first camera frame does
        not pay for compiled shaders, first-use allocations and lazily loaded code."""
        self._provider.warm_up()
        camera, reference = self._provider.camera, self._provider.reference_camera
        self.detect(
            np.zeros((camera.height, camera.width, 3), np.uint8),
            np.zeros((reference.height, reference.width, 3), np.uint8),
        )

    @property
    def cache(self) -> ReferenceCache:
        """What the methods derived from the reference in use (hits and misses counted)."""
        return self._cache

    def detect(
        self, image: np.ndarray, reference: np.ndarray, score_map: bool = True
    ) -> tuple[dict[str, DetectionResult], dict[str, float]]:
        """Run every method on ``image`` against ``reference``; results and ms per method.

        ``score_map=False`` when no one reads the results' ``score`` (the node with no
        ``~/score`` subscriber): the methods then make the cheapest map,
        ``pixel_score="blurred"``, instead of the configured one, unless the image score
        is read from the map (``image_score="map_top"``, the default). The mask, area and
        decision do not depend on ``pixel_score``, so they are the same; the ``continuous``
        ranking map (a second photometric model in the cross score) is skipped.
        """
        params = self._config.params if score_map else self._params_without_map
        results, timings = {}, {}
        for name in self._config.methods:
            start = time.perf_counter()
            results[name] = METHODS[name](
                image, reference, params, backend=self._backend, cache=self._cache
            )
            timings[name] = 1e3 * (time.perf_counter() - start)
        return results, timings

    def process(
        self,
        image: np.ndarray,
        view: View,
        reference: np.ndarray | None = None,
        time_s: float | None = None,
    ) -> ProcessedFrame:
        """Detect anomalies in ``image`` seen from ``view``.

        Parameters
        ----------
        image : numpy.ndarray
            H x W x 3 RGB camera image with the camera's full-resolution size.
        view : View
            Camera pose, lighting and celestial bodies.
        reference : numpy.ndarray, optional
            A pre-rendered reference to use instead of rendering one.
        time_s : float, optional
            The frame's time, for reference reuse (see :meth:`ReferenceProvider.render`).

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
        camera = self._provider.camera
        expected = (camera.height, camera.width)
        if getattr(image, "shape", (None, None))[:2] != expected:
            raise ProcessingError(
                f"image size {getattr(image, 'shape', None)} differs from the camera's "
                f"{expected[1]}x{expected[0]}"
            )
        timings: dict[str, float] = {"render": 0.0}
        reference_camera = None
        if reference is None:
            reference = self._provider.render(view, time_s)
            reference_camera = self._provider.reference_camera
            timings["render"] = 1e3 * (time.perf_counter() - start)
        results, detect_ms = self.detect(image, reference)
        timings.update(detect_ms)
        timings["total"] = 1e3 * (time.perf_counter() - start)
        return ProcessedFrame(reference, results, timings, reference_camera)
