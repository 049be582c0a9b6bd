"""The node's processing threads: render the reference, detect, publish.

GL contexts are bound to the thread that made them, so one thread (the render stage) builds
the :class:`~allo_mrad_ros.pipeline.Pipeline` (its renderer) as soon as ``camera_info`` is known,
rebuilds it when the camera changes, renders with it and closes it: OpenGL is only ever
called from that thread. A parameter change never mutates the running pipeline: the render
stage sees a new :class:`~allo_mrad_ros.ros.parameters.NodeConfig` snapshot and swaps in a
new :class:`~allo_mrad_ros.pipeline.Pipeline` sharing the provider between two frames.

Pipelined (the default): a second thread detects and publishes frame n while the render
thread renders frame n+1, so two cores work at once. Between them is a hand-over of one
frame; the render thread takes the newest image only when the hand-over is empty and the
frame in detection is about one render time from done, so the frame it renders is as fresh
as it can be and is ready when the detect thread is. One detect thread takes frames in the
order they were rendered, so results are published in the order of the images taken.
Serial (``pipelined: false``): one thread renders, then detects and publishes.

Each processed frame's path is timed on the monotonic clock from the publication of its
image (the middleware's source timestamp, where rclpy passes it) through the callback, the
take from the newest-frame slot, the render, the hand-over and the detection to the end of
its publication (:data:`STAGES`); :class:`~.diagnostics.Diagnostics` reports each stage and
the frame's age when taken and when published. A frame older than ``max_input_age_s`` when
the render thread takes it is dropped and counted, not processed: its outputs would describe
a scene that has moved on, and the next frame is at most a frame period away.

A failure once the run is over (:meth:`ProcessingWorker.stop` called, or the ROS context
gone: a publish into a context a signal shut down) is the end of the run, not a failed
frame: the threads end without a report.
"""

from __future__ import annotations

import os
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector.backends import select_backend
from allo_mrad_ros.objects import ObjectsError
from allo_mrad_ros.pipeline import Pipeline, ProcessedFrame
from allo_mrad_ros.render import RendererError
from allo_mrad_ros.ros import messages, process_tuning
from allo_mrad_ros.ros.buffers import HandOver, LatestSlot
from allo_mrad_ros.ros.diagnostics import Diagnostics
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.object_tracking import ObjectsUpdate, ObjectTracking
from allo_mrad_ros.ros.parameters import NodeConfig
from allo_mrad_ros.staging import HOLD_AT, HOLD_MARKER
from allo_mrad_ros.view import View

# Weight of the newest stage time in the running estimates the render thread schedules by.
_ESTIMATE_WEIGHT = 0.2
# The render thread starts this much earlier than its estimate says, as a share of the render
# time plus a constant: starting late stalls the detect thread, starting early only ages the
# frame by the difference.
_EARLY_SHARE = 0.25
_EARLY_MS = 2.0
# How long a waiting thread sleeps before it looks whether the worker stops.
_POLL_S = 0.2
# Test hooks (``ALLO_HOLD_AT``): hold a frame at publish time until the worker is asked to
# stop or the ROS context is gone, or (stuck) for HOLD_S whatever happens.
HOLD_PUBLISH = "node-publish"
HOLD_PUBLISH_STUCK = "node-publish-stuck"
HOLD_S = 60.0
# The stages of a processed frame, in order: each the time between two of its instants, so
# together they make the frame's age when published. ``middleware``: the image's
# publication to the node's callback (transport and the subscription's queue); ``slot``: the
# callback to the render thread's take (the newest-frame slot); ``prepare``: the take to
# the render (camera_info pairing, decoding, pose lookup); ``render``: the render, or the
# reuse of the last one; ``handover``: the rendered frame waiting for the detect thread;
# ``detect``: MRAD; ``publish``: building and sending the outputs.
STAGES = ("middleware", "slot", "prepare", "render", "handover", "detect", "publish")


class Arrival(NamedTuple):
    """An image as the callback stored it, with its instants on the monotonic clock (s).

    A plain ``(msg, received)`` tuple is an Arrival whose publication is unknown.
    """

    msg: Any
    # When the callback ran.
    received: float
    # When its publisher sent it (the middleware's source timestamp); None: unknown (an
    # rclpy that does not pass message info), the age then counts from ``received``.
    published: float | None = None
    # When the middleware received it (its reception timestamp); None: unknown.
    arrived: float | None = None

    @property
    def origin(self) -> float:
        """The instant the frame's age counts from: its publication where known."""
        return self.received if self.published is None else self.published


@dataclass(frozen=True)
class Snapshot:
    """What the callbacks know when a frame is taken: camera, settings, lighting, bodies."""

    intrinsics: CameraIntrinsics | None
    config: NodeConfig
    sun_direction: np.ndarray
    sun_strength: float
    bodies: tuple
    # Why the frame's camera is unknown (no camera_info of its stamp), else None.
    camera_problem: MessageError | None = None
    # No camera_info has arrived since the inputs were (re)subscribed: a start-up state (the
    # two topics are matched apart by discovery), counted and told once, not an input error.
    waiting_for_camera_info: bool = False


@dataclass(frozen=True)
class RenderedFrame:
    """A frame between the stages: the message, its decoded image and its reference."""

    msg: Any
    received: float
    image: np.ndarray
    reference: np.ndarray
    pipeline: Pipeline
    render_ms: float
    # The frame's instants (monotonic s): its arrival, the take from the slot, the render's
    # start and end.
    arrival: Arrival | None = None
    taken: float = 0.0
    render_start: float = 0.0
    render_end: float = 0.0
    # For the object tracker: the view and stamp (s) rendered, the reference's depth (None:
    # not rendered, the frame is not tracked) and the settings in force when it was taken.
    view: View | None = None
    stamp_s: float = 0.0
    depth: np.ndarray | None = None
    config: NodeConfig | None = None


class _RunningMean:
    """An exponentially weighted mean of a stage's time in ms (None before the first)."""

    def __init__(self) -> None:
        self.value: float | None = None

    def add(self, ms: float) -> None:
        self.value = ms if self.value is None else self.value + _ESTIMATE_WEIGHT * (ms - self.value)


class ProcessingWorker:
    """Takes the newest image, renders its reference, detects, hands the result on.

    Parameters
    ----------
    slot : LatestSlot
        Newest ``(Image, monotonic receive time)``; older unprocessed ones are dropped.
    snapshot : callable
        ``(image message or None) -> Snapshot``: the node state for that image (its
        camera_info paired by stamp) or, for None, the latest.
    view_of : callable
        ``(image message, snapshot) -> View or None``: pose and lighting at the image stamp
        (None when no pose is known; the callee counts and logs that).
    publish : callable
        ``(image message, image, ProcessedFrame, score map made)``: publishes the outputs
        (``~/score`` only when the map was made for it).
    diagnostics : Diagnostics
        Counters, error reports, stage timings.
    logger : rclpy logger
        For the renderer-ready line.
    pipelined : bool
        Render the next frame while this one is detected (two threads); False: one thread.
    score_wanted : callable
        Whether anyone reads the score map now (``~/score`` subscribed); if not, the
        detector skips the ranking map (:meth:`~allo_mrad_ros.pipeline.Pipeline.detect`).
    context_ok : callable
        Whether the ROS context lives (``Context.ok``); asked only when something fails,
        to tell a failed frame from the end of the run.
    max_input_age_s : callable
        The oldest a frame may be when taken, in seconds (``max_input_age_s`` in force;
        0: no limit); an older one is dropped and counted as ``frames_dropped_too_old``.
    size_refusal : callable
        ``(image message) -> MessageError or None``: why the image would be refused for
        its size, told without waiting. A frame too old to process is still checked, so
        a camera whose images never fit its camera_info is reported as such, not hidden
        behind the count of frames dropped for their age. Default: never.
    objects_wanted : callable
        ``(NodeConfig) -> bool``: whether to track objects in the frame being taken (asked
        by the render thread, which then renders the reference's depth too; the detect
        thread tracks after detecting and passes the result to ``publish`` as
        ``objects=``). Default: never.
    """

    def __init__(
        self,
        slot: LatestSlot,
        snapshot: Callable[[Any], Snapshot],
        view_of: Callable[[Any, Snapshot], View | None],
        publish: Callable[[Any, np.ndarray, ProcessedFrame, bool], None],
        diagnostics: Diagnostics,
        logger: Any,
        pipelined: bool = True,
        score_wanted: Callable[[], bool] = lambda: True,
        context_ok: Callable[[], bool] = lambda: True,
        max_input_age_s: Callable[[], float] = lambda: 0.0,
        objects_wanted: Callable[[NodeConfig], bool] = lambda _config: False,
        size_refusal: Callable[[Any], MessageError | None] = lambda _msg: None,
    ) -> None:
        self._slot = slot
        self._snapshot = snapshot
        self._view_of = view_of
        self._publish = publish
        self._diagnostics = diagnostics
        self._logger = logger
        self.pipelined = pipelined
        self._score_wanted = score_wanted
        self._context_ok = context_ok
        self._max_input_age_s = max_input_age_s
        self._objects_wanted = objects_wanted
        self._size_refusal = size_refusal
        self._told_waiting_for_camera_info = False
        # Fed by whichever thread detects (one), in the order frames were rendered.
        self._tracking = ObjectTracking()
        hold = os.environ.get(HOLD_AT)
        self._hold = hold if hold in (HOLD_PUBLISH, HOLD_PUBLISH_STUCK) else None
        self._running = True
        self._stopping = threading.Event()
        self._publishing = threading.Lock()
        self._handover: HandOver[RenderedFrame] = HandOver()
        self._render_ms = _RunningMean()
        self._detect_ms = _RunningMean()
        loops = (
            [("mrad_render", self._render_loop), ("mrad_detect", self._detect_loop)]
            if pipelined
            else [("mrad_processing", self._render_loop)]
        )
        self._threads = [
            threading.Thread(target=self._run, args=(loop,), name=name, daemon=True)
            for name, loop in loops
        ]
        for thread in self._threads:
            thread.start()

    # --- threads ------------------------------------------------------------------------

    def _run(self, loop: Callable[[], None]) -> None:
        process_tuning.name_this_thread(threading.current_thread().name)
        try:
            loop()
        finally:
            if self._running:
                self._logger.fatal(
                    f"processing thread stopped ({threading.current_thread().name}): "
                    "no frames are processed"
                )

    def _render_loop(self) -> None:
        """Owns the GL context from its first build to its close."""
        pipeline: Pipeline | None = None
        built_for: tuple | None = None
        try:
            while self._running:
                if self.pipelined:
                    if not self._handover.wait_empty(_POLL_S):
                        continue
                    self._wait_for_detect_to_near_its_end()
                item = self._slot.take(timeout=_POLL_S)
                taken = time.monotonic()
                if not self._running:
                    break
                try:
                    arrival = None if item is None else Arrival(*item)
                    if arrival is not None and self._too_old(arrival, taken):
                        continue
                    state = self._snapshot(None if arrival is None else arrival.msg)
                    pipeline, built_for = self._pipeline_for(state, pipeline, built_for)
                    rendered = (
                        None if arrival is None else self._render(arrival, taken, state, pipeline)
                    )
                    if rendered is not None and self.pipelined:
                        self._handover.put(rendered, timeout=_POLL_S)  # empty: waited above
                    elif rendered is not None:
                        self._detect(rendered)
                except Exception as error:  # one bad frame must not end the thread
                    if self._run_is_over():
                        break
                    self._report_failure(item, error)
        finally:
            if pipeline is not None:
                pipeline.close()

    def _detect_loop(self) -> None:
        while self._running:
            rendered = self._handover.take(timeout=_POLL_S)
            if rendered is None or not self._running:
                continue
            try:
                self._detect(rendered)
            except Exception as error:  # one bad frame must not end the thread
                if self._run_is_over():
                    break
                self._report_failure((rendered.msg, rendered.received), error)

    def _run_is_over(self) -> bool:
        """After a failure: whether the run is over (stopping, or the ROS context gone, as
        when a signal shut it down while this frame was published). If so the other thread
        is woken to end too, and nothing is reported: the failure is the shutdown's."""
        if self._running and self._context_alive():
            return False
        self._running = False
        self._stopping.set()
        self._slot.close()
        self._handover.close()
        return True

    def _context_alive(self) -> bool:
        try:
            return bool(self._context_ok())
        except Exception:  # a context already destroyed cannot even say so
            return False

    def _wait_for_detect_to_near_its_end(self) -> None:
        """Sleep until the frame in detection is about one render time from published.

        The detect thread started on it when it took it from the hand-over; if it is idle
        already, the time is past and the render starts at once."""
        remaining_s = render_delay_s(
            self._handover.taken_at,
            self._detect_ms.value,
            self._render_ms.value,
            time.monotonic(),
        )
        if remaining_s > 0:
            self._stopping.wait(min(remaining_s, 1.0))

    def _too_old(self, arrival: Arrival, taken: float) -> bool:
        """Whether the frame is older than ``max_input_age_s`` at ``taken``; if so it is
        counted (and logged, throttled), not processed."""
        bound_s = self._max_input_age_s()
        age_s = taken - arrival.origin
        if bound_s <= 0 or age_s <= bound_s:
            return False
        refusal = self._size_refusal(arrival.msg)
        if refusal is not None:  # unusable at any age: the cause is what the user must see
            self._diagnostics.report(refusal)
            return True
        self._diagnostics.count("frames_dropped_too_old")
        self._logger.warning(
            f"frame {_stamp_of(arrival)} ns taken {1e3 * age_s:.0f} ms after its publication, "
            f"older than max_input_age_s ({bound_s:g} s): dropped (counted in /diagnostics as "
            "frames_dropped_too_old)",
            throttle_duration_sec=10.0,
        )
        return True

    def _report_failure(self, item: tuple[Any, float] | None, error: Exception) -> None:
        self._diagnostics.report(
            MessageError(
                "internal", f"frame {_stamp_of(item)} ns failed: {type(error).__name__}: {error}"
            ),
            "\n" + traceback.format_exc(),
        )

    # --- stages -------------------------------------------------------------------------

    def _open(self, intrinsics: CameraIntrinsics, config: NodeConfig) -> Pipeline:
        pipeline = Pipeline.open(intrinsics, mesh=config.mesh or None, config=config.pipeline)
        renderer, reference = pipeline.provider.renderer, pipeline.provider.reference_camera
        self._logger.info(
            f"renderer ready: {renderer.backend}, {renderer.triangle_count} triangles, reference "
            f"{reference.width}x{reference.height}; detector "
            f"arrays on {select_backend(config.pipeline.array_backend).name}"
        )
        return pipeline

    def _warm_up(self, pipeline: Pipeline) -> None:
        """Render and detect once before any frame: the first frame would otherwise take
        several frame times (shaders, first-use allocations) and the frames behind it would
        be dropped. A camera the detector cannot take is reported by its frames."""
        try:
            pipeline.warm_up()
        except (RendererError, ValueError):
            return
        self._logger.info("renderer and detector warmed up: processing frames")

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
                pipeline.close()
                pipeline = None
            try:
                pipeline = self._open(state.intrinsics, state.config)
            except (RendererError, ValueError) as error:
                self._diagnostics.report(
                    MessageError("renderer", f"cannot build the renderer: {error}")
                )
                return None, built_for
            self._warm_up(pipeline)
            return pipeline, built_for
        if pipeline is not None and pipeline.config != state.config.pipeline:
            pipeline = pipeline.with_config(state.config.pipeline)
        return pipeline, built_for

    def _render(
        self, arrival: Arrival, taken: float, state: Snapshot, pipeline: Pipeline | None
    ) -> RenderedFrame | None:
        """Decode the image, look its view up and render its reference (None: reported);
        ``taken``: when it was taken from the slot (monotonic s)."""
        stage_start = time.perf_counter()
        msg = arrival.msg
        report = self._diagnostics.report
        if state.waiting_for_camera_info:
            self._diagnostics.count("frames_before_first_camera_info")
            if not self._told_waiting_for_camera_info:
                self._told_waiting_for_camera_info = True
                self._logger.info(
                    f"waiting for the first camera_info on {interface.CAMERA_INFO_TOPIC}: "
                    "frames before it are skipped (counted in /diagnostics as "
                    "frames_before_first_camera_info)"
                )
            return None
        if state.camera_problem is not None:
            report(state.camera_problem)
            return None
        if pipeline is None:
            report(
                MessageError(
                    "camera_info",
                    f"no usable camera_info on {interface.CAMERA_INFO_TOPIC}; frame skipped",
                )
            )
            return None
        intrinsics = pipeline.provider.camera
        try:
            image = messages.image_to_rgb(msg, (intrinsics.width, intrinsics.height))
            view = self._view_of(msg, state)
            if view is None:
                return None
            start, render_start = time.perf_counter(), time.monotonic()
            provider = pipeline.provider
            stamp_s = messages.stamp_to_ns(msg.header.stamp) / 1e9
            depth = None
            if self._objects_wanted(state.config):
                reference, depth = provider.render_with_depth(view, stamp_s)
            else:
                reference = provider.render(view, stamp_s)
            render_ms = 1e3 * (time.perf_counter() - start)
            render_end = time.monotonic()
            reused = provider.reuse is not None and provider.reuse.last_decision.reuse
            self._diagnostics.count("references_reused" if reused else "references_rendered")
        except MessageError as error:
            report(error)
            return None
        except RendererError as error:
            report(MessageError("renderer", f"reference rendering failed: {error}"))
            return None
        except ValueError as error:
            report(MessageError("processing", f"frame rejected: {error}"))
            return None
        # The whole stage (a TF lookup may wait) is what the detect thread waits for.
        self._render_ms.add(1e3 * (time.perf_counter() - stage_start))
        return RenderedFrame(
            msg,
            arrival.received,
            image,
            reference,
            pipeline,
            render_ms,
            arrival,
            taken,
            render_start,
            render_end,
            view=view,
            stamp_s=stamp_s,
            depth=depth,
            config=state.config,
        )

    def _detect(self, rendered: RenderedFrame) -> None:
        """Detect, publish (unless stopping), count and time one rendered frame."""
        start = time.perf_counter()
        try:
            self._detect_and_publish(rendered)
        finally:
            self._detect_ms.add(1e3 * (time.perf_counter() - start))

    def _detect_and_publish(self, rendered: RenderedFrame) -> None:
        detect_start = time.monotonic()
        try:
            score_map = self._score_wanted()
            detected = rendered.pipeline.detect(
                rendered.image, rendered.reference, score_map=score_map, view=rendered.view
            )
            detect_end = time.monotonic()
        except ValueError as error:
            self._diagnostics.report(MessageError("processing", f"frame rejected: {error}"))
            return
        frame = detected.with_render(
            rendered.render_ms, rendered.pipeline.provider.reference_camera
        )
        objects = self._track(rendered, frame)
        with self._publishing:
            # Checked under the lock stop() takes: nothing is published once stop() returns.
            if not self._running:
                return
            if self._hold is not None:
                self._hold_at_publish()
            if objects is None:
                self._publish(rendered.msg, rendered.image, frame, score_map)
            else:
                self._publish(rendered.msg, rendered.image, frame, score_map, objects=objects)
        published = time.monotonic()
        timings = frame_timings_ms(rendered, detect_start, detect_end, published)
        if objects is not None:
            timings["objects"] = objects.tracker_ms  # a part of ``publish``
        self._diagnostics.stages.record(timings)
        self._diagnostics.count("frames_processed")
        # The frames ~/anomaly flagged, by the decision in force.
        if rendered.config is not None and rendered.config.decision == "objects":
            anomalous = objects is not None and objects.anomalous
        else:
            anomalous = frame.primary.anomalous
        if anomalous:
            self._diagnostics.count("anomalous_frames")

    def _track(self, rendered: RenderedFrame, frame: ProcessedFrame) -> ObjectsUpdate | None:
        """The object tracker's result for a frame rendered with its depth (None: not
        tracked, or its input refused and reported). The tracker gets the image's
        full-resolution camera: the regions' boxes and centroids are in the image's pixels,
        whatever the detector's processing scale; the depth is at the reference's size."""
        if rendered.depth is None or rendered.view is None or rendered.config is None:
            self._tracking.skip()
            return None
        result = frame.primary
        try:
            update = self._tracking.update(
                camera=rendered.pipeline.provider.camera,
                params=rendered.config.objects.params,
                regions=result.regions,
                pose=rendered.view.T_station_camera,
                depth=rendered.depth,
                stamp=rendered.stamp_s,
                mask=result.mask,
            )
        except ObjectsError as error:
            self._diagnostics.report(MessageError("objects", f"frame not tracked: {error}"))
            return None
        self._diagnostics.set_values(
            {
                "objects_tentative": str(update.count("tentative")),
                "objects_confirmed": str(update.count("confirmed")),
            }
        )
        return update

    def _hold_at_publish(self) -> None:
        """The test hooks at publish time: a signal lands there on any machine. Creates the
        file ``ALLO_HOLD_MARKER`` names, then holds the frame: ``node-publish`` until the
        worker is asked to stop or the ROS context is gone, ``node-publish-stuck`` for
        :data:`HOLD_S` whatever happens (a publish that does not return)."""
        marker = os.environ.get(HOLD_MARKER)
        if marker:
            Path(marker).touch()
        deadline = time.monotonic() + HOLD_S
        while time.monotonic() < deadline:
            if self._hold == HOLD_PUBLISH and (
                self._stopping.is_set() or not self._context_alive()
            ):
                return
            time.sleep(0.002)

    # --- control ------------------------------------------------------------------------

    def is_alive(self) -> bool:
        """Whether every processing thread runs."""
        return all(thread.is_alive() for thread in self._threads)

    def join(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` in all for the threads to end (after :meth:`stop`)."""
        deadline = time.monotonic() + timeout_s
        for thread in self._threads:
            if thread.is_alive() and threading.current_thread() is not thread:
                thread.join(timeout=max(0.0, deadline - time.monotonic()))

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop: no output is published after this returns (a publish under way ends first);
        waits up to ``timeout_s`` for the frames in progress (the threads are daemons, so one
        stuck in rendering cannot keep the process alive)."""
        self._stopping.set()  # first: whatever waits for it wakes before the lock is taken
        with self._publishing:
            self._running = False
        self._slot.close()
        self._handover.close()
        self.join(timeout_s)


def render_delay_s(
    taken_at: float | None, detect_ms: float | None, render_ms: float | None, now: float
) -> float:
    """How long the render thread waits before it takes the next image, in seconds.

    Until the frame in detection (taken from the hand-over at monotonic ``taken_at``) is
    about one render from done by the running estimates ``detect_ms`` and ``render_ms``,
    less a margin: 0 without a frame or an estimate, or when that time is past at ``now``.
    """
    if taken_at is None or detect_ms is None or render_ms is None:
        return 0.0
    lead_ms = detect_ms - (1.0 + _EARLY_SHARE) * render_ms - _EARLY_MS
    return max(0.0, taken_at + lead_ms / 1e3 - now)


def frame_timings_ms(
    rendered: RenderedFrame, detect_start: float, detect_end: float, published: float
) -> dict[str, float]:
    """A processed frame's :data:`STAGES`, the part of ``middleware`` it spent in the
    subscription's queue (``middleware_queue``: the middleware's reception to the callback),
    its ages when taken and when published (``age_taken``, ``age_published``: from its
    publication, else from the callback) and ``receive_to_publish`` (the callback to the end
    of publication), in ms, from its instants (monotonic s). ``middleware`` and
    ``middleware_queue`` only where the middleware's timestamps are known."""
    arrival = rendered.arrival or Arrival(rendered.msg, rendered.received)
    instants = [
        arrival.published,
        arrival.received,
        rendered.taken,
        rendered.render_start,
        rendered.render_end,
        detect_start,
        detect_end,
        published,
    ]
    timings = {
        stage: 1e3 * (end - start)
        for stage, start, end in zip(STAGES, instants[:-1], instants[1:], strict=True)
        if start is not None
    }
    if arrival.arrived is not None:
        timings["middleware_queue"] = 1e3 * (arrival.received - arrival.arrived)
    timings["age_taken"] = 1e3 * (rendered.taken - arrival.origin)
    timings["age_published"] = 1e3 * (published - arrival.origin)
    timings["receive_to_publish"] = 1e3 * (published - arrival.received)
    return timings


def _stamp_of(item: tuple[Any, float] | None) -> str:
    """The stamp (ns) of a taken item for a log line, or ``?``."""
    try:
        return str(messages.stamp_to_ns(item[0].header.stamp))
    except (AttributeError, TypeError):
        return "?"
