"""Objects evaluation (``allo-bag evaluate --objects``): MRAD with the reference's depth over a
sequence or bag, the object tracker fed per trajectory in frame order, and the metrics of
:mod:`.object_metrics`.

The run has two halves so that tracker parameters can be chosen without running the detector
again: :func:`detect_frames` renders and detects every frame once (in ``jobs`` processes)
and keeps what the tracker and the metrics need (:class:`ObjectFrame`, a few kilobytes a
frame); :func:`track` feeds those frames to an
:class:`~allo_mrad_ros.objects.ObjectTracker`, reset at each new trajectory.

A frame's trajectory is the sequence's ``trajectory`` column where there is one; otherwise
(bags, sequences without the column) a new trajectory starts where the stamps go back or
jump by more than three times the median frame period.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector.regions import Region
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.evaluation.evaluate import (
    WorkerSetup,
    check_run_options,
    release_worker_state,
    start_worker,
    worker_pipeline,
)
from allo_mrad_ros.evaluation.object_metrics import (
    HEADLINE_METRICS,
    ConfirmedSample,
    FrameTruth,
    MatchRules,
    ObjectMetrics,
    assign,
    frame_period_s,
    match_distances,
    object_metrics,
)
from allo_mrad_ros.evaluation.parallel import RunClock, run_frames
from allo_mrad_ros.evaluation.sources import (
    EvalFrame,
    FrameSource,
    SequenceSource,
    open_sequence,
)
from allo_mrad_ros.objects import ObjectParams, ObjectTracker, TrackedObject
from allo_mrad_ros.pipeline import PipelineConfig
from allo_mrad_ros.sequence import GroundTruthObject

# A stamp step beyond this many median frame periods starts a new trajectory (no column).
_GAP_PERIODS = 3.0


class ObjectEvaluationError(InvalidInput):
    """The objects evaluation cannot run: an input without ground-truth objects, a bad
    option, or a frame that failed (the message names it)."""


@dataclass(frozen=True)
class ObjectFrame:
    """What the tracker and the metrics need of one detected frame (picklable, small).

    ``mask_pixels`` are the flat indices of the detection mask's set pixels (the mask is
    rebuilt for the tracker); ``depth`` the reference's z depth; ``showing`` the ids of the
    ground-truth objects with pixels in the frame; ``frame_flagged`` the detector's verdict.
    """

    index: int
    split: str
    stamp_ns: int
    pose: np.ndarray
    regions: tuple[Region, ...]
    depth: np.ndarray
    mask_pixels: np.ndarray
    frame_flagged: bool
    showing: frozenset[int]
    detect_ms: float
    trajectory: str = ""


@dataclass
class ObjectRun:
    """Every detected frame of a run, in input order, with the camera and the objects."""

    name: str
    camera: CameraIntrinsics
    objects: tuple[GroundTruthObject, ...]
    frames: list[ObjectFrame]
    wall_s: float = 0.0

    def split(self, name: str) -> ObjectRun:
        """The frames of split ``name`` only."""
        frames = [f for f in self.frames if f.split == name]
        return ObjectRun(self.name, self.camera, self.objects, frames, self.wall_s)

    @property
    def splits(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(f.split for f in self.frames))


@dataclass(frozen=True)
class ObjectEvaluationConfig:
    """Options of :func:`evaluate_objects`.

    ``pipeline``: render settings and detector parameters (the first method's regions are
    tracked); ``params``: the tracker's; ``split``: the split (None: ``test`` if present,
    else every frame); ``jobs``: detection worker processes; ``rules``: the matching rules.
    """

    pipeline: PipelineConfig = field(default_factory=lambda: PipelineConfig(methods=("MRAD",)))
    params: ObjectParams = field(default_factory=ObjectParams)
    split: str | None = None
    jobs: int = 1
    progress: bool = True
    rules: MatchRules = field(default_factory=MatchRules)

    def __post_init__(self) -> None:
        try:
            check_run_options(self.jobs, None)
        except InvalidInput as error:
            raise ObjectEvaluationError(str(error)) from None


@dataclass
class ObjectEvaluation:
    """The result of :func:`evaluate_objects`."""

    input: str
    name: str
    split: str | None
    frames: int
    params: ObjectParams
    metrics: ObjectMetrics
    tracker_ms: list[float]
    detect_ms: list[float]
    wall_s: float

    def as_dict(self) -> dict[str, Any]:
        """The report: metrics, timings, the tracker's parameters."""
        return {
            "input": self.input,
            "name": self.name,
            "split": self.split,
            **self.metrics.as_dict(),
            "tracker_ms_per_frame": _median(self.tracker_ms),
            "detect_ms_per_frame": _median(self.detect_ms),
            "params": dict(vars(self.params)),
        }


def _median(values: Sequence[float]) -> float | None:
    return float(np.median(values)) if len(values) else None


# ----------------------------------------------------------------- detection
def _detect_frame(frame: EvalFrame) -> ObjectFrame:
    try:
        processed = worker_pipeline().process(
            frame.image, frame.view, time_s=frame.stamp_ns / 1e9, depth=True
        )
    except (ValueError, RuntimeError) as error:
        raise ObjectEvaluationError(f"frame {frame.name} (index {frame.index}): {error}") from None
    result = processed.primary
    showing = frozenset()
    if frame.instances is not None:
        showing = frozenset(int(v) for v in np.unique(frame.instances) if v)
    depth = processed.reference_depth
    assert depth is not None  # asked for with depth=True
    return ObjectFrame(
        index=frame.index,
        split=frame.split,
        stamp_ns=frame.stamp_ns,
        pose=np.asarray(frame.view.T_station_camera, dtype=np.float64),
        regions=tuple(result.regions),
        depth=np.asarray(depth, dtype=np.float32),
        mask_pixels=np.flatnonzero(result.mask).astype(np.int32),
        frame_flagged=bool(result.anomalous),
        showing=showing,
        detect_ms=float(processed.timings_ms.get("total", 0.0)),
    )


def trajectory_keys(
    source: FrameSource, indices: Sequence[int], stamps_ns: Sequence[int]
) -> list[str]:
    """The trajectory of each frame: the sequence's ``trajectory`` column, else segments of
    the stamps (see the module text); prefixed with the split."""
    splits = {h.index: h.split for h in source.headers}
    if isinstance(source, SequenceSource):
        rows = [source.sequence.frames[i].extra.get("trajectory", "") for i in indices]
        if all(rows):
            return [f"{splits[i]}/{row}" for i, row in zip(indices, rows, strict=True)]
    keys: list[str] = []
    steps = np.diff(np.asarray(stamps_ns, dtype=np.int64))
    period = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    segment = 0
    for k, index in enumerate(indices):
        if k and (
            steps[k - 1] <= 0
            or (period > 0 and steps[k - 1] > _GAP_PERIODS * period)
            or splits[index] != splits[indices[k - 1]]
        ):
            segment += 1
        keys.append(f"{splits[index]}/{segment}")
    return keys


def detect_frames(
    source: FrameSource | str | PathLike[str],
    *,
    pipeline: PipelineConfig | None = None,
    split: str | None = None,
    jobs: int = 1,
    progress: bool = True,
) -> ObjectRun:
    """Render (with depth) and detect every frame of ``split`` (None: every frame) once.

    Raises
    ------
    ObjectEvaluationError
        For an input without ground-truth objects, or a frame that failed.
    """
    if not isinstance(source, FrameSource):
        source = open_sequence(source)
    if not source.objects:
        raise ObjectEvaluationError(
            f"{source.path}: no ground-truth objects table (a sequence of format version 2, "
            "e.g. allo-synth generate --preset objects, or its bag)"
        )
    pipeline = pipeline or PipelineConfig(methods=("MRAD",))
    check_run_options(jobs, None)
    indices = source.select(split)
    setup = WorkerSetup(source.mesh, source.camera, pipeline)
    clock = RunClock()
    frames = list(
        run_frames(
            source.frames(indices),
            len(indices),
            initializer=start_worker,
            initargs=(setup,),
            work=_detect_frame,
            jobs=jobs,
            progress=progress,
            desc="objects",
            clock=clock,
        )
    )
    if jobs == 1:
        release_worker_state()
    keys = trajectory_keys(source, indices, [f.stamp_ns for f in frames])
    frames = [_with_trajectory(f, k) for f, k in zip(frames, keys, strict=True)]
    return ObjectRun(source.name, source.camera, source.objects, frames, clock.seconds)


def _with_trajectory(frame: ObjectFrame, key: str) -> ObjectFrame:
    return ObjectFrame(**{**vars(frame), "trajectory": key})


# ----------------------------------------------------------------- tracking
def _masks(run: ObjectRun) -> Iterator[np.ndarray]:
    """Each frame's detection mask, rebuilt in one buffer (reused: read before the next)."""
    camera = run.camera
    mask = np.zeros(camera.height * camera.width, dtype=np.uint8)
    previous: np.ndarray | None = None
    for frame in run.frames:
        if previous is not None:
            mask[previous] = 0
        mask[frame.mask_pixels] = 255
        previous = frame.mask_pixels
        yield mask.reshape(camera.height, camera.width)


def track(
    run: ObjectRun,
    params: ObjectParams,
    *,
    records: list[tuple[TrackedObject, ...]] | None = None,
) -> tuple[list[list[ConfirmedSample]], list[float]]:
    """Feed ``run``'s frames to a tracker, reset at each new trajectory (``records``, when
    given, receives every frame's objects as the tracker returned them).

    Returns
    -------
    confirmed : list of list of ConfirmedSample
        Per frame, the confirmed objects after it.
    milliseconds : list of float
        The tracker's time per frame (``ObjectTracker.update`` alone).
    """
    tracker = ObjectTracker(params, run.camera)
    confirmed: list[list[ConfirmedSample]] = []
    timings: list[float] = []
    current: str | None = None
    for frame, mask in zip(run.frames, _masks(run), strict=True):
        if frame.trajectory != current:
            tracker.reset()
            current = frame.trajectory
        start = time.perf_counter()
        objects = tracker.update(
            frame.regions, frame.pose, frame.depth, frame.stamp_ns * 1e-9, mask=mask
        )
        timings.append(1e3 * (time.perf_counter() - start))
        if records is not None:
            records.append(objects)
        confirmed.append(
            [
                ConfirmedSample(o.id, o.position, o.in_view)
                for o in objects
                if o.state == "confirmed"
            ]
        )
    return confirmed, timings


def truths(run: ObjectRun) -> list[FrameTruth]:
    """The :class:`FrameTruth` of every frame of ``run``."""
    return [
        FrameTruth(f.trajectory, f.stamp_ns, f.pose[:3, 3], f.showing, f.frame_flagged)
        for f in run.frames
    ]


def detection_coverage(
    run: ObjectRun, instances: Callable[[int], np.ndarray | None]
) -> dict[str, dict[str, int]]:
    """How much of each showing object the detector's mask covers, per placement.

    The tracker can only follow what the detector marks, so this separates a detection
    miss from a tracking miss. An object-frame is an object showing in a frame (its
    instance pixels); it counts as ``touched`` when at least one of its pixels lies under
    the detection mask and ``half_covered`` when at least half of them do.

    Parameters
    ----------
    run : ObjectRun
        The detected frames.
    instances : callable
        The instance mask (uint16, the camera's size) of the frame with a given input
        index (:attr:`ObjectFrame.index`), or None where the frame has none.

    Returns
    -------
    dict
        Per placement (the objects table's ``placement`` column, ``-`` where there is
        none) and ``all``: ``object_frames``, ``touched``, ``half_covered``.
    """
    placements = {o.id: o.extra.get("placement", "-") or "-" for o in run.objects}
    size = run.camera.height * run.camera.width
    out: dict[str, dict[str, int]] = {}
    for frame in run.frames:
        if not frame.showing:
            continue
        labels = instances(frame.index)
        if labels is None:
            continue
        flat = labels.reshape(-1)
        if flat.size != size:
            raise ObjectEvaluationError(
                f"frame index {frame.index}: instance mask of {flat.size} pixels, "
                f"the camera has {size}"
            )
        pixels = np.bincount(flat, minlength=1)
        under = np.bincount(flat[frame.mask_pixels], minlength=pixels.size)
        for object_id in frame.showing:
            total = int(pixels[object_id]) if object_id < pixels.size else 0
            if total == 0:
                continue
            covered = int(under[object_id]) if object_id < under.size else 0
            for group in (placements.get(object_id, "-"), "all"):
                row = out.setdefault(group, {"object_frames": 0, "touched": 0, "half_covered": 0})
                row["object_frames"] += 1
                row["touched"] += covered > 0
                row["half_covered"] += 2 * covered >= total
    return out


@dataclass(frozen=True)
class ObjectDiagnosis:
    """Why one ground-truth object was recalled or missed (:func:`diagnose_objects`).

    Attributes
    ----------
    id, type, placement, trajectory
        The object and the trajectory it shows in.
    frames_showing : int
        Frames with its instance pixels.
    eligible : bool
        In view long enough to count for recall.
    frames_touched : int
        Frames where a region (any score) covers some of its instance pixels: pixels under
        the detection mask inside the region's box.
    frames_tracked : int
        Of those, frames where such a region scores at least ``min_region_score`` (the
        tracker takes it).
    regions : int
        Such regions given to the tracker, all frames.
    tracks : int
        Distinct tracks those regions went to (1: one id; more: new tracks were spawned).
    main_track_regions : int
        The regions of the track that got most of them.
    confirmed_tracks : int
        Of those tracks, how many were ever confirmed.
    main_track_waiting : int
        In-view frames the main track spent tentative after its ``confirm_hits``-th hit.
    main_track_unresolved : int
        Of those, the frames in which parallax had not yet placed it nearer than
        ``max_range`` (:attr:`~allo_mrad_ros.objects.TrackedObject.range_resolved`): what
        holds back a thing whose rays barely converge over the arm's baseline.
    matched : bool
        Matched one-to-one in the evaluation.
    distance_m, tolerance_m : float or None
        The nearest of its confirmed tracks (last confirmed estimate) from the object at that
        stamp, and the match distance there (``max(floor, fraction * range)``).
    cause : str
        The first stage that lost it: ``no region``, ``regions score low``, ``not
        confirmed``, ``beyond match distance``, ``lost in assignment``, or ``matched``.
    """

    id: int
    type: str
    placement: str
    trajectory: str
    frames_showing: int
    eligible: bool
    frames_touched: int
    frames_tracked: int
    regions: int
    tracks: int
    main_track_regions: int
    confirmed_tracks: int
    main_track_waiting: int
    main_track_unresolved: int
    matched: bool
    distance_m: float | None
    tolerance_m: float | None
    cause: str


def _object_regions(frame: ObjectFrame, labels: np.ndarray, width: int) -> dict[int, list[int]]:
    """Per showing object, the regions of ``frame`` covering some of its instance pixels
    under the detection mask (inside the region's box)."""
    flat = labels.reshape(-1)
    under = frame.mask_pixels[flat[frame.mask_pixels] > 0]
    out: dict[int, list[int]] = {}
    if under.size == 0:
        return out
    ids = flat[under]
    ys, xs = np.divmod(under, width)
    for index, region in enumerate(frame.regions):
        x, y, w, h = region.box
        inside = (xs >= x) & (xs < x + w) & (ys >= y) & (ys < y + h)
        for object_id in np.unique(ids[inside]):
            out.setdefault(int(object_id), []).append(index)
    return out


def diagnose_objects(
    run: ObjectRun,
    params: ObjectParams,
    instances: Callable[[int], np.ndarray | None],
    rules: MatchRules | None = None,
) -> list[ObjectDiagnosis]:
    """Follow each ground-truth object of ``run`` through detection, association,
    confirmation and matching, and say where it was lost.

    ``instances`` gives a frame's instance mask by its input index (as for
    :func:`detection_coverage`). The tracker runs as in :func:`score_run`.
    """
    rules = rules or MatchRules()
    records: list[tuple[TrackedObject, ...]] = []
    track(run, params, records=records)
    by_id = {o.id: o for o in run.objects}
    width = run.camera.width
    out: list[ObjectDiagnosis] = []
    trajectories: dict[str, list[int]] = {}
    for i, frame in enumerate(run.frames):
        trajectories.setdefault(frame.trajectory, []).append(i)
    for trajectory, indices in trajectories.items():
        period = frame_period_s([run.frames[i].stamp_ns for i in indices])
        shown: dict[int, int] = {}
        touched: dict[int, int] = {}
        tracked: dict[int, int] = {}
        track_regions: dict[int, dict[int, int]] = {}
        last: dict[int, tuple[int, np.ndarray]] = {}
        # Per track: in-view frames tentative with the hits to confirm, and of those the
        # frames its range was unresolved.
        waiting: dict[int, list[int]] = {}
        for i in indices:
            frame = run.frames[i]
            region_track = {o.region: o.id for o in records[i] if o.region is not None}
            for o in records[i]:
                if o.state == "confirmed":
                    last[o.id] = (i, np.asarray(o.position, dtype=np.float64))
                elif o.state == "tentative" and o.in_view and o.hits >= params.confirm_hits:
                    tally = waiting.setdefault(o.id, [0, 0])
                    tally[0] += 1
                    tally[1] += not o.range_resolved
            for object_id in frame.showing:
                shown[object_id] = shown.get(object_id, 0) + 1
            labels = instances(frame.index) if frame.showing else None
            if labels is None:
                continue
            for object_id, regions in _object_regions(frame, labels, width).items():
                touched[object_id] = touched.get(object_id, 0) + 1
                taken = [region_track[r] for r in regions if r in region_track]
                tracked[object_id] = tracked.get(object_id, 0) + bool(taken)
                counts = track_regions.setdefault(object_id, {})
                for track_id in taken:
                    counts[track_id] = counts.get(track_id, 0) + 1
        # The evaluation's one-to-one match (object_metrics), on the last estimates.
        confirmed_ids = sorted(last)
        true_ids = sorted(shown)
        estimates = [
            (run.frames[i].stamp_ns, run.frames[i].pose[:3, 3], estimate)
            for i, estimate in (last[track_id] for track_id in confirmed_ids)
        ]
        distance, tolerance = match_distances(estimates, [by_id[o] for o in true_ids], rules)
        matched = {true_ids[c] for _, c in assign(distance, tolerance)}
        for c, object_id in enumerate(true_ids):
            item = by_id[object_id]
            counts = track_regions.get(object_id, {})
            confirmed_rows = [r for r, t in enumerate(confirmed_ids) if t in counts]
            near = min(confirmed_rows, key=lambda r: distance[r, c], default=None)
            main = max(counts, key=counts.__getitem__, default=None)
            main_waiting, main_unresolved = waiting.get(main, (0, 0))
            if object_id in matched:
                cause = "matched"
            elif not touched.get(object_id):
                cause = "no region"
            elif not counts:
                cause = "regions score low"
            elif near is None:
                cause = "not confirmed"
            elif distance[near, c] > tolerance[near, c]:
                cause = "beyond match distance"
            else:
                cause = "lost in assignment"
            out.append(
                ObjectDiagnosis(
                    id=object_id,
                    type=item.type,
                    placement=str(item.extra.get("placement") or "-"),
                    trajectory=trajectory,
                    frames_showing=shown[object_id],
                    eligible=shown[object_id] * period >= rules.min_view_s - 1e-9,
                    frames_touched=touched.get(object_id, 0),
                    frames_tracked=tracked.get(object_id, 0),
                    regions=sum(counts.values()),
                    tracks=len(counts),
                    main_track_regions=max(counts.values(), default=0),
                    confirmed_tracks=len(confirmed_rows),
                    main_track_waiting=main_waiting,
                    main_track_unresolved=main_unresolved,
                    matched=object_id in matched,
                    distance_m=None if near is None else float(distance[near, c]),
                    tolerance_m=None if near is None else float(tolerance[near, c]),
                    cause=cause,
                )
            )
    return out


def score_run(
    run: ObjectRun, params: ObjectParams, rules: MatchRules | None = None
) -> tuple[ObjectMetrics, list[float]]:
    """Track ``run`` with ``params`` and measure it; also the tracker's ms per frame."""
    confirmed, timings = track(run, params)
    return object_metrics(truths(run), confirmed, run.objects, rules=rules), timings


def evaluate_objects(
    source: FrameSource | str | PathLike[str],
    config: ObjectEvaluationConfig | None = None,
) -> ObjectEvaluation:
    """Detect every frame of a split, track the objects, measure them (module text)."""
    config = config or ObjectEvaluationConfig()
    if not isinstance(source, FrameSource):
        source = open_sequence(source)
    split = config.split if config.split is not None else source.default_split()
    start = time.perf_counter()
    run = detect_frames(
        source, pipeline=config.pipeline, split=split, jobs=config.jobs, progress=config.progress
    )
    metrics, timings = score_run(run, config.params, config.rules)
    return ObjectEvaluation(
        input=str(source.path),
        name=source.name,
        split=split,
        frames=len(run.frames),
        params=config.params,
        metrics=metrics,
        tracker_ms=timings,
        detect_ms=[f.detect_ms for f in run.frames],
        wall_s=time.perf_counter() - start,
    )


def objects_markdown(result: ObjectEvaluation) -> str:
    """The metrics as Markdown tables: summary, both decisions, per type and placement."""
    data = result.as_dict()

    def fmt(value: object, digits: int = 3) -> str:
        if value is None:
            return "-"
        if isinstance(value, float):
            return f"{value:.{digits}f}"
        return str(value)

    frame = data["frame_level"]
    lines = [
        f"# Objects: {result.name} ({result.split or 'all'}, {result.frames} frames)",
        "",
        "| metric | value |",
        "|---|---:|",
    ]
    for key in (*HEADLINE_METRICS, "tracker_ms_per_frame"):
        lines.append(f"| {key} | {fmt(data[key])} |")
    lines += [
        "",
        f"Frames: {frame['positive_frames']} with an object showing, "
        f"{frame['normal_frames']} normal.",
        "",
        "| decision | frame recall | false-alarm rate | normal frames flagged |",
        "|---|---:|---:|---:|",
    ]
    for name in ("objects", "frame"):
        row = frame[name]
        lines.append(
            f"| {name} | {fmt(row['recall'])} | {fmt(row['false_alarm_rate'])} | "
            f"{row['normal_flagged']} |"
        )
    for title, key in (("type", "per_type"), ("placement", "per_placement")):
        lines += [
            "",
            f"| {title} | objects | recall | error median | error p90 | confirmation s | "
            "frame recall (objects) | frame recall (frame) |",
            "|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for label, row in data[key].items():
            lines.append(
                f"| {label} | {row['objects']} | {fmt(row['recall'])} | "
                f"{fmt(row['error_m_median'])} | {fmt(row['error_m_p90'])} | "
                f"{fmt(row['confirmation_s_median'])} | {fmt(row['frame_recall_objects'])} | "
                f"{fmt(row['frame_recall_frame'])} |"
            )
    return "\n".join(lines) + "\n"
