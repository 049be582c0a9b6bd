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
import traceback
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
        self._publishing = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="mrad_processing", daemon=True)
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
        try:
            self._loop()
        finally:
            if self._running:
                self._logger.fatal("processing thread stopped: no frames are processed")

    def _loop(self) -> None:
        pipeline: Pipeline | None = None
        built_for: tuple | None = None
        while self._running:
            item = self._slot.take(timeout=0.2)
            if not self._running:
                break
            try:
                state = self._snapshot()
                pipeline, built_for = self._pipeline_for(state, pipeline, built_for)
                if item is not None:
                    self._process(item, state, pipeline)
            except Exception as error:  # one bad frame must not end the thread
                self._diagnostics.report(
                    MessageError(
                        "internal",
                        f"frame {_stamp_of(item)} ns failed: {type(error).__name__}: {error}",
                    ),
                    "\n" + traceback.format_exc(),
                )

    def _pipeline_for(
        self, state: Snapshot, pipeline: Pipeline | None, built_for: tuple | None
    ) -> tuple[Pipeline | None, tuple | None]:
        """The pipeline for this snapshot: (re)built for new intrinsics, renderer settings or
        mesh (one attempt per change, so a camera that cannot be rendered is reported once),
        swapped for new detector settings."""
        if state.intrinsics is None:
            return pipeline, built_for
        wanted = (state.intrinsics, state.config.mesh, state.config.pipeline.render)
        if wanted != built_for:
            built_for = wanted
            if pipeline is not None:
                pipeline.provider.close()
                pipeline = None
            try:
                provider = self._provider(state.intrinsics, state.config)
                return Pipeline(provider, state.config.pipeline), built_for
            except (RendererError, ValueError) as error:
                self._diagnostics.report(
                    MessageError("renderer", f"cannot build the renderer: {error}")
                )
                return None, built_for
        if pipeline is not None and pipeline.config != state.config.pipeline:
            pipeline = pipeline.with_config(state.config.pipeline)
        return pipeline, built_for

    def _process(self, item: tuple[Any, float], state: Snapshot, pipeline: Pipeline | None) -> None:
        msg, received = item
        report = self._diagnostics.report
        if pipeline is None:
            report(
                MessageError(
                    "camera_info",
                    f"no usable camera_info on {interface.CAMERA_INFO_TOPIC}; frame skipped",
                )
            )
            return
        intrinsics = pipeline.provider.camera
        try:
            image = messages.image_to_rgb(msg, (intrinsics.width, intrinsics.height))
            view = self._view_of(msg, state)
            if view is None:
                return
            frame = pipeline.process(image, view)
        except MessageError as error:
            report(error)
            return
        except RendererError as error:
            report(MessageError("renderer", f"reference rendering failed: {error}"))
            return
        except ValueError as error:
            report(MessageError("processing", f"frame rejected: {error}"))
            return
        with self._publishing:
            # Checked under the lock stop() takes: nothing is published once stop() returns.
            if not self._running:
                return
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

    def is_alive(self) -> bool:
        """Whether the processing thread runs."""
        return self._thread.is_alive()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop: no output is published after this returns; waits up to ``timeout_s`` for the
        frame in progress (the thread is a daemon, so one stuck in rendering cannot keep the
        process alive)."""
        with self._publishing:
            self._running = False
        self._slot.close()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=timeout_s)


def _stamp_of(item: tuple[Any, float] | None) -> str:
    """The stamp (ns) of a taken item for a log line, or ``?``."""
    try:
        return str(messages.stamp_to_ns(item[0].header.stamp))
    except (AttributeError, TypeError):
        return "?"
