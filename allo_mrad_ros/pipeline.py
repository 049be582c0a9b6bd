"""One camera frame in, detections out: render the reference of a view once, run every detector.

The node, ``allo-bag evaluate``/``ablate`` and the benchmarks all build a
:class:`PipelineConfig` (:class:`RenderSettings`, :class:`~allo_mrad_ros.detector.MradParams`,
methods, array backend) and run frames through a :class:`Pipeline` (:meth:`Pipeline.open`
makes one), so what is measured offline is what runs online. A :class:`Pipeline` is
immutable: a change of parameters builds a new one that shares the
:class:`ReferenceProvider` (the GL context), it never mutates a running one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from os import PathLike
from typing import Any

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import METHODS, DetectionResult, MradParams
from allo_mrad_ros.detector.backends import ARRAY_BACKENDS, ArrayBackendError, select_backend
from allo_mrad_ros.detector.reference_cache import ReferenceCache
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.render.provider import ReferenceProvider
from allo_mrad_ros.render.settings import RenderSettings
from allo_mrad_ros.view import View

# The cheapest score map of MradParams.pixel_score, made when no one reads the map.
UNREAD_PIXEL_SCORE = "blurred"


class ProcessingError(InvalidInput):
    """A frame or a configuration cannot be processed (image size, method name, option)."""


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


@dataclass(frozen=True)
class ProcessedFrame:
    """The reference used and each method's detection for one frame.

    What :meth:`Pipeline.process` and :meth:`Pipeline.detect` return.

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
    reference_depth : numpy.ndarray or None
        The reference's z depth in metres (0 where space is in view), when asked for
        (:meth:`Pipeline.process` with ``depth=True``); else None.
    """

    reference: np.ndarray
    results: dict[str, DetectionResult]
    timings_ms: dict[str, float] = field(default_factory=dict)
    reference_camera: CameraIntrinsics | None = None
    reference_depth: np.ndarray | None = None

    @property
    def primary(self) -> DetectionResult:
        """The first method's result (MRAD for the node)."""
        return next(iter(self.results.values()))

    def with_render(self, render_ms: float, reference_camera: CameraIntrinsics) -> ProcessedFrame:
        """This frame with the time its reference took to render and the camera it was
        rendered for (the node renders on one thread and detects on another)."""
        methods = {name: self.timings_ms[name] for name in self.results}
        total = render_ms + sum(methods.values())
        return replace(
            self,
            timings_ms={"render": render_ms, **methods, "total": total},
            reference_camera=reference_camera,
        )


class Pipeline:
    """Render-then-detect for a stream of frames from one camera: render once, detect many.

    Build one with :meth:`open`, and close it (or use it in a ``with`` block) to release its
    renderer::

        with Pipeline.open(camera, mesh="station.glb", config=config) as pipeline:
            frame = pipeline.process(image, view)

    Parameters
    ----------
    provider : ReferenceProvider
        Renders the references; shared by pipelines built with :meth:`with_config`.
    config : PipelineConfig, optional
        Parameters and methods (its render settings are the provider's); default: the
        provider's render settings and the default detector parameters.
    cache : ReferenceCache, optional
        What the methods derived from the reference in use (:meth:`with_config` shares it).
    """

    def __init__(
        self,
        provider: ReferenceProvider,
        config: PipelineConfig | None = None,
        *,
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
        except ArrayBackendError as error:
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

    @classmethod
    def open(
        cls,
        camera: CameraIntrinsics,
        *,
        mesh: str | PathLike[str] | Any | None = None,
        config: PipelineConfig | None = None,
    ) -> Pipeline:
        """A pipeline with a renderer of its own for ``camera``'s frames.

        Its references are rendered as ``config.render`` says; nothing else repeats it.
        The renderer's OpenGL context belongs to the calling thread: build, use and close
        the pipeline there.

        Parameters
        ----------
        camera : CameraIntrinsics
            Full-resolution intrinsics of the camera whose frames are processed.
        mesh : path-like, trimesh object or None
            Station model in metres in the station frame (None: the package's model).
        config : PipelineConfig, optional
            Render settings, detector parameters, methods and array backend (default:
            :class:`PipelineConfig`'s defaults).

        Raises
        ------
        allo_mrad_ros.render.RendererError
            When no OpenGL context can be made.
        ProcessingError
            For an array backend this machine cannot run.
        ValueError
            For a model that cannot be loaded.
        """
        config = config or PipelineConfig()
        provider = ReferenceProvider(mesh, camera, config.render)
        try:
            return cls(provider, config)
        except Exception:
            provider.close()
            raise

    def close(self) -> None:
        """Release the renderer (its OpenGL context), which the pipelines :meth:`with_config`
        made share: close one of them when done with all. Closing twice is harmless."""
        self._provider.close()

    def __enter__(self) -> Pipeline:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

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
        return Pipeline(self._provider, config, cache=self._cache)

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

    def render(self, view: View, *, time_s: float | None = None) -> np.ndarray:
        """The reference RGB image of ``view`` at the reference scale, the first half of
        :meth:`process` (see :meth:`ReferenceProvider.render`)."""
        return self._provider.render(view, time_s)

    def render_with_depth(
        self, view: View, *, time_s: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`render`'s reference and its z depth in metres, 0 where space is in view
        (see :meth:`ReferenceProvider.render_with_depth`)."""
        return self._provider.render_with_depth(view, time_s)

    def detect(
        self,
        image: np.ndarray,
        reference: np.ndarray,
        *,
        score_map: bool = True,
        view: View | None = None,
    ) -> ProcessedFrame:
        """Run every method on ``image`` against ``reference``, the second half of
        :meth:`process`; the frame's ``render`` time is 0 and its reference camera None.

        ``view``, the view the reference was rendered for, tells the methods where the Sun
        and the bodies are in the image (MRAD's ``sun_glare`` and ``body_margin``); without
        it neither rule acts.

        ``score_map=False`` when no one reads the results' ``score`` (the node with no
        ``~/score`` subscriber): the methods then make the cheapest map,
        ``pixel_score="blurred"``, instead of the configured one, unless the image score
        is read from the map (``image_score="map_top"``, the default). The mask, area and
        decision do not depend on ``pixel_score``, so they are the same; the ``continuous``
        ranking map (a second photometric model in the cross score) is skipped.
        """
        params = self._config.params if score_map else self._params_without_map
        sun_pixel, body_discs = None, []
        if view is not None:
            camera = self._provider.camera
            if params.sun_glare > 0.0:
                sun_pixel = view.sun_pixel(camera)
            if params.body_margin > 0.0:
                body_discs = view.body_discs(camera)
        results, timings = {}, {"render": 0.0}
        for name in self._config.methods:
            start = time.perf_counter()
            results[name] = METHODS[name](
                image,
                reference,
                params,
                backend=self._backend,
                cache=self._cache,
                sun_pixel=sun_pixel,
                body_discs=body_discs,
            )
            timings[name] = 1e3 * (time.perf_counter() - start)
        timings["total"] = sum(timings.values())
        return ProcessedFrame(reference, results, timings)

    def process(
        self,
        image: np.ndarray,
        view: View,
        *,
        reference: np.ndarray | None = None,
        time_s: float | None = None,
        depth: bool = False,
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
        depth : bool
            Also render the reference's depth (:attr:`ProcessedFrame.reference_depth`);
            off by default, as it costs a depth read back. Ignored with ``reference``.

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
        camera = self._provider.camera
        expected = (camera.height, camera.width)
        if getattr(image, "shape", (None, None))[:2] != expected:
            raise ProcessingError(
                f"image size {getattr(image, 'shape', None)} differs from the camera's "
                f"{expected[1]}x{expected[0]}"
            )
        if reference is not None:
            return self.detect(image, reference, view=view)
        start = time.perf_counter()
        reference_depth = None
        if depth:
            reference, reference_depth = self.render_with_depth(view, time_s=time_s)
        else:
            reference = self.render(view, time_s=time_s)
        render_ms = 1e3 * (time.perf_counter() - start)
        frame = self.detect(image, reference, view=view).with_render(
            render_ms, self._provider.reference_camera
        )
        return frame if reference_depth is None else replace(frame, reference_depth=reference_depth)
