"""Object-level and frame-level metrics of tracked objects against ground-truth objects.

Pure functions of what a run saw, per frame (:class:`FrameTruth`: the trajectory, stamp,
camera position, the ground-truth objects showing pixels, the detector's per-frame verdict)
and what the tracker reported (:class:`ConfirmedSample`: each confirmed object's id,
position and whether the tracker holds it in view). No pipeline, no tracker: the tests build
both by hand.

Definitions (``docs/evaluation.md``, Objects):

- a ground-truth object *shows* in a frame when its instance mask has pixels there; it is
  *in view for at least 1 s* when it shows in frames totalling at least ``min_view_s``
  (frames times the trajectory's frame period);
- per trajectory, each confirmed object (an id confirmed in any frame) is represented by
  its last confirmed estimate; it *matches* a ground-truth object of that trajectory when
  the distance between that estimate and the object's position at that frame's stamp is at
  most ``max(match_floor_m, match_fraction * range)``, the range from that frame's camera to
  the true object; matching is one-to-one, by optimal assignment
  (:func:`scipy.optimize.linear_sum_assignment`, most matches, then least total distance);
- recall: matched objects among those in view for at least ``min_view_s``; precision:
  matched confirmed objects among all confirmed objects (every trajectory);
- 3-D error: ``|estimate - truth|`` in every frame where a matched object is confirmed
  and its true object shows, with the true range in ``error_range_m``; median and p90;
- time to confirmation: the stamp of the first frame its matched track is confirmed in,
  minus that of the third frame showing the object (objects in view >= ``min_view_s``);
- false objects per minute: confirmed objects on trajectories where no ground-truth object
  ever shows, over those trajectories' duration;
- frame level: a frame is positive when a ground-truth object shows; ``decision: objects``
  flags a frame iff a confirmed object is in view, ``decision: frame`` iff the detector's
  verdict says so; recall over positive frames, false-alarm rate over the others, and
  ``normal_frames_flagged_ratio`` = normal frames flagged by objects over those flagged by
  frame.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from allo_mrad_ros.sequence import GroundTruthObject

# Cost of an inadmissible pair in the assignment: never chosen over an admissible one.
_FORBIDDEN = 1e9

#: The headline keys of :meth:`ObjectMetrics.as_dict`, in the order a summary table shows them.
HEADLINE_METRICS = (
    "recall",
    "precision",
    "error_m_median",
    "error_m_p90",
    "confirmation_s_median",
    "false_objects_per_min",
    "normal_frames_flagged_ratio",
    "objects",
    "confirmed",
    "true_confirmed",
    "false_objects_anomaly_free",
    "anomaly_free_minutes",
)


@dataclass(frozen=True)
class FrameTruth:
    """What is known of one frame, apart from the tracker.

    Attributes
    ----------
    trajectory : str
        The trajectory (tracks never cross one).
    stamp_ns : int
        The frame's time.
    camera_position : numpy.ndarray
        (3,) the camera centre in the station frame.
    showing : frozenset of int
        Ids of the ground-truth objects whose instance mask has pixels in this frame.
    frame_flagged : bool
        The detector's per-frame verdict (``decision: frame``).
    """

    trajectory: str
    stamp_ns: int
    camera_position: np.ndarray
    showing: frozenset[int]
    frame_flagged: bool


@dataclass(frozen=True)
class ConfirmedSample:
    """One confirmed object as the tracker reported it after a frame."""

    id: int
    position: np.ndarray
    in_view: bool


@dataclass(frozen=True)
class MatchRules:
    """How confirmed objects are matched and what is counted.

    ``match_floor_m`` and ``match_fraction``: the match distance ``max(floor, fraction *
    range)``; ``min_view_s``: the view time an object needs to count for recall;
    ``error_range_m``: the true ranges at which the 3-D error is measured.
    """

    match_floor_m: float = 0.3
    match_fraction: float = 0.05
    min_view_s: float = 1.0
    error_range_m: tuple[float, float] = (2.0, 25.0)


@dataclass
class GroupStats:
    """Per-object counts and samples of one group (all, a type, a placement)."""

    eligible: int = 0
    recalled: int = 0
    errors: list[float] = field(default_factory=list)
    delays: list[float] = field(default_factory=list)
    positive_frames: int = 0
    frames_by_objects: int = 0
    frames_by_frame: int = 0

    def as_dict(self) -> dict[str, Any]:
        """The group's metrics (None where there is nothing to measure)."""
        return {
            "objects": self.eligible,
            "recall": _ratio(self.recalled, self.eligible),
            "error_m_median": _quantile(self.errors, 0.5),
            "error_m_p90": _quantile(self.errors, 0.9),
            "confirmation_s_median": _quantile(self.delays, 0.5),
            "positive_frames": self.positive_frames,
            "frame_recall_objects": _ratio(self.frames_by_objects, self.positive_frames),
            "frame_recall_frame": _ratio(self.frames_by_frame, self.positive_frames),
        }


@dataclass
class ObjectMetrics:
    """The metrics of one run (see the module text); :meth:`as_dict` for the report."""

    overall: GroupStats
    per_type: dict[str, GroupStats]
    per_placement: dict[str, GroupStats]
    confirmed: int
    true_confirmed: int
    false_objects_free: int
    free_minutes: float
    frames: int
    positive_frames: int
    normal_frames: int
    normal_by_objects: int
    normal_by_frame: int
    trajectories: int
    free_trajectories: int

    @property
    def recall(self) -> float | None:
        return _ratio(self.overall.recalled, self.overall.eligible)

    @property
    def precision(self) -> float | None:
        return _ratio(self.true_confirmed, self.confirmed)

    @property
    def false_objects_per_min(self) -> float | None:
        if self.free_minutes <= 0:
            return None
        return self.false_objects_free / self.free_minutes

    @property
    def normal_frames_flagged_ratio(self) -> float | None:
        """Normal frames flagged by ``decision: objects`` over those flagged by ``frame``
        (None when ``frame`` flags none)."""
        return _ratio(self.normal_by_objects, self.normal_by_frame)

    def as_dict(self) -> dict[str, Any]:
        overall = self.overall.as_dict()
        return {
            "recall": self.recall,
            "precision": self.precision,
            "error_m_median": overall["error_m_median"],
            "error_m_p90": overall["error_m_p90"],
            "confirmation_s_median": overall["confirmation_s_median"],
            "false_objects_per_min": self.false_objects_per_min,
            "normal_frames_flagged_ratio": self.normal_frames_flagged_ratio,
            "objects": self.overall.eligible,
            "confirmed": self.confirmed,
            "true_confirmed": self.true_confirmed,
            "false_objects_anomaly_free": self.false_objects_free,
            "anomaly_free_minutes": self.free_minutes,
            "trajectories": self.trajectories,
            "anomaly_free_trajectories": self.free_trajectories,
            "frames": self.frames,
            "frame_level": {
                "positive_frames": self.positive_frames,
                "normal_frames": self.normal_frames,
                "objects": {
                    "recall": overall["frame_recall_objects"],
                    "false_alarm_rate": _ratio(self.normal_by_objects, self.normal_frames),
                    "normal_flagged": self.normal_by_objects,
                },
                "frame": {
                    "recall": overall["frame_recall_frame"],
                    "false_alarm_rate": _ratio(self.normal_by_frame, self.normal_frames),
                    "normal_flagged": self.normal_by_frame,
                },
            },
            "per_type": {k: v.as_dict() for k, v in sorted(self.per_type.items())},
            "per_placement": {k: v.as_dict() for k, v in sorted(self.per_placement.items())},
        }


def _ratio(numerator: int, denominator: int) -> float | None:
    return numerator / denominator if denominator else None


def _quantile(values: Sequence[float], q: float) -> float | None:
    """The ``q`` quantile (linear interpolation, NumPy's default), None when empty."""
    return float(np.quantile(values, q)) if len(values) else None


def frame_period_s(stamps_ns: Sequence[int]) -> float:
    """A trajectory's frame period: the median step between its stamps (0 for one frame)."""
    if len(stamps_ns) < 2:
        return 0.0
    return float(np.median(np.diff(np.asarray(stamps_ns, dtype=np.int64)))) * 1e-9


def match_distances(
    estimates: Sequence[tuple[int, Sequence[float], np.ndarray]],
    objects: Sequence[GroundTruthObject],
    rules: MatchRules,
) -> tuple[np.ndarray, np.ndarray]:
    """Each estimate's distance from each true object, and the match distance there.

    Parameters
    ----------
    estimates : sequence of tuple
        Per confirmed object: the stamp (ns) of the frame of its estimate, that frame's
        camera position and the estimate (station frame).
    objects : sequence of GroundTruthObject
        The true objects, each where it is at the estimate's stamp.
    rules : MatchRules
        ``match_floor_m`` and ``match_fraction``.

    Returns
    -------
    distance, tolerance : numpy.ndarray
        (estimates, objects): ``|estimate - truth|`` and ``max(match_floor_m,
        match_fraction * range)``, the range from that frame's camera to the truth.
    """
    distance = np.zeros((len(estimates), len(objects)))
    tolerance = np.zeros_like(distance)
    for r, (stamp_ns, camera_position, estimate) in enumerate(estimates):
        camera = np.asarray(camera_position, dtype=np.float64)
        for c, item in enumerate(objects):
            truth = item.position_at(stamp_ns)
            distance[r, c] = float(np.linalg.norm(estimate - truth))
            true_range = float(np.linalg.norm(truth - camera))
            tolerance[r, c] = max(rules.match_floor_m, rules.match_fraction * true_range)
    return distance, tolerance


def assign(distance: np.ndarray, tolerance: np.ndarray) -> list[tuple[int, int]]:
    """One-to-one pairs ``(row, column)`` with ``distance <= tolerance``: the most pairs,
    then the least total distance (rows: confirmed objects, columns: true objects)."""
    if distance.size == 0:
        return []
    admissible = distance <= tolerance
    if not admissible.any():
        return []
    cost = np.where(admissible, distance, _FORBIDDEN)
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if admissible[r, c]]


def _label(item: GroundTruthObject, key: str) -> str:
    return item.type if key == "type" else (item.extra.get(key) or "unknown")


def object_metrics(
    truths: Sequence[FrameTruth],
    confirmed: Sequence[Sequence[ConfirmedSample]],
    objects: Iterable[GroundTruthObject],
    *,
    rules: MatchRules | None = None,
) -> ObjectMetrics:
    """The metrics of a run (see the module text).

    Parameters
    ----------
    truths : sequence of FrameTruth
        Every frame, in time order within each trajectory.
    confirmed : sequence of sequence of ConfirmedSample
        Per frame (aligned with ``truths``), the confirmed objects after that frame.
    objects : iterable of GroundTruthObject
        The ground-truth objects (ids as in ``FrameTruth.showing``).
    rules : MatchRules, optional
        The match distance, view time and error ranges (default :class:`MatchRules`).

    Returns
    -------
    ObjectMetrics
    """
    rules = rules or MatchRules()
    if len(truths) != len(confirmed):
        raise ValueError(f"{len(truths)} frames of truth but {len(confirmed)} of objects")
    by_id: Mapping[int, GroundTruthObject] = {o.id: o for o in objects}
    frames_of: dict[str, list[int]] = defaultdict(list)
    for i, truth in enumerate(truths):
        frames_of[truth.trajectory].append(i)

    overall = GroupStats()
    per_type: dict[str, GroupStats] = defaultdict(GroupStats)
    per_placement: dict[str, GroupStats] = defaultdict(GroupStats)
    totals = {"confirmed": 0, "true": 0, "free_false": 0}
    free_minutes = 0.0
    free_trajectories = 0

    def groups(item: GroundTruthObject) -> list[GroupStats]:
        return [overall, per_type[_label(item, "type")], per_placement[_label(item, "placement")]]

    for frames in frames_of.values():
        stamps = [truths[i].stamp_ns for i in frames]
        period = frame_period_s(stamps)
        showing_frames: dict[int, list[int]] = defaultdict(list)
        for i in frames:
            for object_id in truths[i].showing:
                showing_frames[object_id].append(i)
        unknown = sorted(set(showing_frames) - set(by_id))
        if unknown:
            raise ValueError(f"objects {unknown} show in the frames but are not in the table")
        # Each confirmed id: its first confirmed frame and its last estimate.
        first: dict[int, int] = {}
        last: dict[int, tuple[int, np.ndarray]] = {}
        for i in frames:
            for sample in confirmed[i]:
                first.setdefault(sample.id, i)
                last[sample.id] = (i, np.asarray(sample.position, dtype=np.float64))
        track_ids = sorted(last)
        true_ids = sorted(showing_frames)
        totals["confirmed"] += len(track_ids)
        if not true_ids:
            free_trajectories += 1
            totals["free_false"] += len(track_ids)
            free_minutes += len(frames) * period / 60.0
        estimates = [
            (truths[i].stamp_ns, truths[i].camera_position, estimate)
            for i, estimate in (last[track_id] for track_id in track_ids)
        ]
        distance, tolerance = match_distances(estimates, [by_id[o] for o in true_ids], rules)
        pairs = assign(distance, tolerance)
        totals["true"] += len(pairs)
        match_of = {true_ids[c]: track_ids[r] for r, c in pairs}

        for object_id, shown in showing_frames.items():
            item = by_id[object_id]
            eligible = len(shown) * period >= rules.min_view_s - 1e-9
            track_id = match_of.get(object_id)
            for group in groups(item):
                group.eligible += eligible
                group.recalled += eligible and track_id is not None
            if track_id is None:
                continue
            if eligible and len(shown) >= 3:
                delay = (truths[first[track_id]].stamp_ns - truths[shown[2]].stamp_ns) * 1e-9
                for group in groups(item):
                    group.delays.append(delay)
            for i in shown:
                sample = next((s for s in confirmed[i] if s.id == track_id), None)
                if sample is None:
                    continue
                truth = item.position_at(truths[i].stamp_ns)
                true_range = float(np.linalg.norm(truth - truths[i].camera_position))
                low, high = rules.error_range_m
                if not low <= true_range <= high:
                    continue
                error = float(np.linalg.norm(np.asarray(sample.position) - truth))
                for group in groups(item):
                    group.errors.append(error)

    frame_counts = _frame_level(truths, confirmed, by_id, overall, per_type, per_placement)
    return ObjectMetrics(
        overall=overall,
        per_type=dict(per_type),
        per_placement=dict(per_placement),
        confirmed=totals["confirmed"],
        true_confirmed=totals["true"],
        false_objects_free=totals["free_false"],
        free_minutes=free_minutes,
        frames=len(truths),
        trajectories=len(frames_of),
        free_trajectories=free_trajectories,
        **frame_counts,
    )


def _frame_level(
    truths: Sequence[FrameTruth],
    confirmed: Sequence[Sequence[ConfirmedSample]],
    by_id: Mapping[int, GroundTruthObject],
    overall: GroupStats,
    per_type: dict[str, GroupStats],
    per_placement: dict[str, GroupStats],
) -> dict[str, int]:
    """Both decisions' counts per frame; per group, the frames where one of its objects
    shows."""
    normal = normal_objects = normal_frame = 0
    for truth, samples in zip(truths, confirmed, strict=True):
        by_objects = any(s.in_view for s in samples)
        if not truth.showing:
            normal += 1
            normal_objects += by_objects
            normal_frame += truth.frame_flagged
            continue
        members = [overall]
        for key, table in (("type", per_type), ("placement", per_placement)):
            labels = {_label(by_id[i], key) for i in truth.showing}
            members.extend(table[label] for label in sorted(labels))
        for group in members:
            group.positive_frames += 1
            group.frames_by_objects += by_objects
            group.frames_by_frame += truth.frame_flagged
    return {
        "positive_frames": len(truths) - normal,
        "normal_frames": normal,
        "normal_by_objects": normal_objects,
        "normal_by_frame": normal_frame,
    }
