"""The node's processing thread: owns the OpenGL context and an immutable pipeline.

GL contexts are bound to the thread that made them, so one thread builds the
:class:`~allo_mrad_ros.pipeline.ReferenceProvider` (as soon as ``camera_info`` is known),
renders and detects. A parameter change never mutates the running pipeline: the worker
sees a new :class:`~allo_mrad_ros.ros.parameters.NodeConfig` snapshot and swaps in a new
:class:`~allo_mrad_ros.pipeline.Pipeline` sharing the provider between two frames.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.pipeline import Pipeline, ProcessedFrame, ReferenceProvider
from allo_mrad_ros.render import RendererError
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.buffers import LatestSlot
from allo_mrad_ros.ros.diagnostics import Diagnostics
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.parameters import NodeConfig
from allo_mrad_ros.view import View


@dataclass(frozen=True)
class Snapshot:
    """What the callbacks know when a frame is taken: camera, settings, lighting, bodies."""

    intrinsics: CameraIntrinsics | None
    config: NodeConfig
    sun_direction: np.ndarray
    sun_strength: float
    bodies: tuple


class ProcessingWorker:
    """Takes the newest image, renders its reference, detects, hands the result on.

    Parameters
    ----------
    slot : LatestSlot
        Newest ``(Image, monotonic receive time)``; older unprocessed ones are dropped.
    snapshot : callable
        Returns the current :class:`Snapshot` (taken under the node's lock).
    view_of : callable
        ``(image message, snapshot) -> View or None``: pose and lighting at the image stamp
        (None when no pose is known; the callee counts and logs that).
    publish : callable
        ``(image message, image, ProcessedFrame)``: publishes the outputs.
    diagnostics : Diagnostics
        Counters, error reports, stage timings.
    logger : rclpy logger
        For the renderer-ready line.
    """

    def __init__(
        self,
        slot: LatestSlot,
        snapshot: Callable[[], Snapshot],
        view_of: Callable[[Any, Snapshot], View | None],
        publish: Callable[[Any, np.ndarray, ProcessedFrame], None],
        diagnostics: Diagnostics,
        logger: Any,
    ) -> None:
        self._slot = slot
        self._snapshot = snapshot
        self._view_of = view_of
        self._publish = publish
        self._diagnostics = diagnostics
        self._logger = logger
        self._running = True
        self._thread = threading.Thread(target=self._run, name="mrad_processing")
        self._thread.start()

    def _provider(self, intrinsics: CameraIntrinsics, config: NodeConfig) -> ReferenceProvider:
        provider = ReferenceProvider(config.mesh or None, intrinsics, config.pipeline.render)
        renderer = provider.renderer
        self._logger.info(
            f"renderer ready: {renderer.backend}, {renderer.triangle_count} triangles, reference "
            f"{renderer.output_intrinsics.width}x{renderer.output_intrinsics.height}"
        )
        return provider

    def _run(self) -> None:
        pipeline: Pipeline | None = None
        built_for: CameraIntrinsics | None = None
        report = self._diagnostics.report
        while self._running:
            item = self._slot.take(timeout=0.2)
            state = self._snapshot()
            if state.intrinsics is not None and (pipeline is None or built_for != state.intrinsics):
                # Build (or rebuild) as soon as camera_info is known, not when a frame waits.
                try:
                    provider = self._provider(state.intrinsics, state.config)
                    pipeline = Pipeline(provider, state.config.pipeline)
                    built_for = state.intrinsics
                except (RendererError, ValueError) as error:
                    report(MessageError("renderer", f"cannot build the renderer: {error}"))
                    pipeline = None
                    continue
            elif pipeline is not None and pipeline.config != state.config.pipeline:
                pipeline = pipeline.with_config(state.config.pipeline)
            if item is None:
                continue
            msg, received = item
            if pipeline is None:
                report(
                    MessageError(
                        "camera_info",
                        f"no camera_info on {interface.CAMERA_INFO_TOPIC} yet; frame skipped",
                    )
                )
                continue
            try:
                image = messages.image_to_rgb(msg, (built_for.width, built_for.height))
                view = self._view_of(msg, state)
                if view is None:
                    continue
                frame = pipeline.process(image, view)
            except MessageError as error:
                report(error)
                continue
            except RendererError as error:
                report(MessageError("renderer", f"reference rendering failed: {error}"))
                continue
            except ValueError as error:
                report(MessageError("processing", f"frame rejected: {error}"))
                continue
            self._publish(msg, image, frame)
            self._diagnostics.stages.record(
                {
                    "render": frame.timings_ms["render"],
                    "detect": frame.timings_ms["MRAD"],
                    "receive_to_publish": 1e3 * (time.monotonic() - received),
                }
            )
            self._diagnostics.count("frames_processed")
            if frame.primary.anomalous:
                self._diagnostics.count("anomalous_frames")

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop after the current frame."""
        self._running = False
        self._slot.close()
        if self._thread.is_alive():
            self._thread.join(timeout=timeout_s)
