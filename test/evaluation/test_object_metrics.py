"""The objects metrics on hand-built ground truth and tracks, against simple independent
computations: one-to-one matching (a brute force over permutations), the match distance,
the view time recall counts, the time to confirmation, the error's range window, false
objects per minute and the frame-level counts of both decisions."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from allo_mrad_ros.evaluation.object_metrics import (
    ConfirmedSample,
    FrameTruth,
    MatchRules,
    assign,
    object_metrics,
)
from allo_mrad_ros.evaluation.objects import trajectory_keys
from allo_mrad_ros.evaluation.sources import FrameHeader, FrameSource
from allo_mrad_ros.sequence import GroundTruthObject

PERIOD_NS = 100_000_000  # 10 Hz
ORIGIN = np.zeros(3)


def thing(
    object_id: int,
    position,
    *,
    kind: str = "wrench",
    placement: str = "space",
    velocity=(0.0, 0.0, 0.0),
) -> GroundTruthObject:
    return GroundTruthObject(
        id=object_id,
        type=kind,
        stamp_ns=0,
        position=np.asarray(position, float),
        velocity=np.asarray(velocity, float),
        quaternion=np.array([0.0, 0.0, 0.0, 1.0]),
        size=np.full(3, 0.3),
        extra={"placement": placement},
    )


def frames(trajectory: str, count: int, showing=(), flagged=(), start: int = 0, camera=ORIGIN):
    """``count`` frames at 10 Hz; ``showing`` maps a frame number to the ids showing."""
    showing = dict(showing)
    return [
        FrameTruth(
            trajectory,
            (start + k) * PERIOD_NS,
            np.asarray(camera, float),
            frozenset(showing.get(k, ())),
            k in set(flagged),
        )
        for k in range(count)
    ]


def sample(track_id: int, position, in_view: bool = True) -> ConfirmedSample:
    return ConfirmedSample(track_id, np.asarray(position, float), in_view)


# ------------------------------------------------------------------ matching
def brute_force(distance: np.ndarray, tolerance: np.ndarray) -> tuple[int, float]:
    """The most admissible one-to-one pairs, then the least total distance, by trying every
    injection of the smaller side into the larger."""
    rows, cols = distance.shape
    best = (0, 0.0)
    if rows <= cols:
        options = (
            zip(range(rows), p, strict=True) for p in itertools.permutations(range(cols), rows)
        )
    else:
        options = (
            zip(p, range(cols), strict=True) for p in itertools.permutations(range(rows), cols)
        )
    for option in options:
        pairs = [(r, c) for r, c in option if distance[r, c] <= tolerance[r, c]]
        total = sum(distance[r, c] for r, c in pairs)
        if len(pairs) > best[0] or (len(pairs) == best[0] and total < best[1]):
            best = (len(pairs), total)
    return best


@pytest.mark.parametrize("seed", range(40))
def test_assignment_is_one_to_one_with_the_most_pairs_then_the_least_distance(seed):
    rng = np.random.default_rng(seed)
    rows, cols = rng.integers(1, 5, size=2)
    distance = rng.uniform(0.0, 1.0, (rows, cols))
    tolerance = np.full((rows, cols), 0.6)
    pairs = assign(distance, tolerance)
    assert len({r for r, _ in pairs}) == len(pairs) == len({c for _, c in pairs})
    assert all(distance[r, c] <= tolerance[r, c] for r, c in pairs)
    count, total = brute_force(distance, tolerance)
    assert len(pairs) == count
    assert sum(distance[r, c] for r, c in pairs) == pytest.approx(total)


def test_one_confirmed_object_between_two_true_ones_matches_one_of_them_only():
    objects = [thing(1, (0.0, 0.0, 10.0)), thing(2, (0.2, 0.0, 10.0))]
    truth = frames("a", 20, {k: (1, 2) for k in range(20)})
    confirmed = [[sample(7, (0.1, 0.0, 10.0))] for _ in truth]
    metrics = object_metrics(truth, confirmed, objects)
    assert metrics.overall.eligible == 2 and metrics.overall.recalled == 1
    assert metrics.recall == 0.5 and metrics.precision == 1.0


def test_two_confirmed_objects_on_one_true_one_leave_one_false():
    objects = [thing(1, (0.0, 0.0, 10.0))]
    truth = frames("a", 20, {k: (1,) for k in range(20)})
    confirmed = [[sample(7, (0.05, 0.0, 10.0)), sample(8, (0.0, 0.1, 10.0))] for _ in truth]
    metrics = object_metrics(truth, confirmed, objects)
    assert (metrics.confirmed, metrics.true_confirmed) == (2, 1)
    assert metrics.precision == 0.5 and metrics.recall == 1.0
    # The nearer one is the match: its error is what is measured.
    assert metrics.overall.errors == pytest.approx([0.05] * 20)


@pytest.mark.parametrize(
    ("true_range", "offset", "matches"),
    [
        (4.0, 0.29, True),  # 5 % of 4 m is 0.2 m: the 0.3 m floor holds
        (4.0, 0.31, False),
        (20.0, 0.99, True),  # 5 % of 20 m is 1 m
        (20.0, 1.01, False),
    ],
)
def test_the_match_distance_is_the_larger_of_0_3_m_and_5_percent_of_the_range(
    true_range, offset, matches
):
    objects = [thing(1, (0.0, 0.0, true_range))]
    truth = frames("a", 12, {k: (1,) for k in range(12)})
    confirmed = [[sample(3, (offset, 0.0, true_range))] for _ in truth]
    metrics = object_metrics(truth, confirmed, objects)
    assert metrics.recall == (1.0 if matches else 0.0)
    assert metrics.precision == (1.0 if matches else 0.0)


def test_the_last_confirmed_estimate_is_matched_against_the_object_where_it_then_is():
    # A drifting object: 0.5 m/s along x; the estimate follows it.
    objects = [thing(1, (0.0, 0.0, 10.0), velocity=(0.5, 0.0, 0.0))]
    truth = frames("a", 20, {k: (1,) for k in range(20)})
    confirmed = [[sample(4, (0.05 * k, 0.0, 10.0))] for k in range(20)]
    assert object_metrics(truth, confirmed, objects).recall == 1.0
    frozen = [[sample(4, (0.0, 0.0, 10.0))] for _ in range(20)]  # 0.95 m behind at the end
    assert object_metrics(truth, frozen, objects).recall == 0.0


# ------------------------------------------------------------------ recall, timing
def test_recall_counts_objects_showing_for_at_least_one_second():
    objects = [thing(1, (0.0, 0.0, 10.0)), thing(2, (5.0, 0.0, 10.0))]
    # Object 1 shows in 10 frames (1.0 s), object 2 in 9 (0.9 s); neither is confirmed.
    showing = {k: (1,) for k in range(10)} | {k: (2,) for k in range(20, 29)}
    truth = frames("a", 40, showing)
    metrics = object_metrics(truth, [[] for _ in truth], objects)
    assert metrics.overall.eligible == 1 and metrics.recall == 0.0
    assert (
        object_metrics(
            truth, [[] for _ in truth], objects, rules=MatchRules(min_view_s=0.9)
        ).overall.eligible
        == 2
    )


def test_time_to_confirmation_counts_from_the_third_frame_showing_the_object():
    objects = [thing(1, (0.0, 0.0, 10.0))]
    showing = {k: (1,) for k in range(3, 30) if k != 4}  # shows at 3, 5, 6, ...
    truth = frames("a", 30, showing, start=17)
    confirmed = [[sample(2, (0.0, 0.0, 10.0))] if k >= 9 else [] for k in range(30)]
    metrics = object_metrics(truth, confirmed, objects)
    third = sorted(showing)[2]  # frame 6
    assert metrics.overall.delays == pytest.approx([(9 - third) * 0.1])
    assert metrics.as_dict()["confirmation_s_median"] == pytest.approx(0.3)


def test_the_error_is_measured_where_the_object_shows_at_2_to_25_m():
    objects = [thing(1, (0.0, 0.0, 10.0))]
    # The camera stands 1 m, 10 m and 30 m from the object in turn.
    truth = []
    for k, z in enumerate([9.0, 9.0, 0.0, 0.0, -20.0, -20.0]):
        truth.append(FrameTruth("a", k * PERIOD_NS, np.array([0, 0, z]), frozenset({1}), False))
    truth.append(FrameTruth("a", 6 * PERIOD_NS, np.zeros(3), frozenset(), False))
    confirmed = [[sample(5, (0.0, 0.1 * (k + 1), 10.0))] for k in range(7)]
    confirmed[-1] = [sample(5, (0.0, 0.2, 10.0))]  # the last estimate matches
    metrics = object_metrics(truth, confirmed, objects, rules=MatchRules(min_view_s=0.0))
    assert metrics.overall.errors == pytest.approx([0.3, 0.4])


# ------------------------------------------------------------------ false objects
def test_false_objects_per_minute_count_confirmed_objects_on_anomaly_free_trajectories():
    objects = [thing(1, (0.0, 0.0, 10.0))]
    truth = (
        frames("with", 20, {k: (1,) for k in range(20)})
        + frames("free1", 30, start=100)
        + frames("free2", 30, start=200)
    )
    confirmed = [[] for _ in truth]
    confirmed[5] = [sample(1, (0.0, 0.0, 10.0)), sample(9, (3.0, 0.0, 10.0))]  # one false
    confirmed[20 + 10] = [sample(2, (1.0, 1.0, 5.0))]  # free1
    confirmed[20 + 11] = [sample(2, (1.0, 1.0, 5.0))]  # the same object again
    confirmed[50 + 3] = [sample(3, (2.0, 1.0, 5.0), in_view=False)]  # free2
    metrics = object_metrics(truth, confirmed, objects)
    # Two objects over 60 frames at 10 Hz: 6 s, a tenth of a minute.
    assert metrics.false_objects_free == 2 and metrics.free_trajectories == 2
    assert metrics.free_minutes == pytest.approx(0.1)
    assert metrics.false_objects_per_min == pytest.approx(20.0)
    assert (metrics.confirmed, metrics.true_confirmed) == (4, 1)


# ------------------------------------------------------------------ frame level
@pytest.mark.parametrize("seed", range(5))
def test_frame_level_counts_of_both_decisions_match_a_plain_loop(seed):
    rng = np.random.default_rng(seed)
    objects = [
        thing(1, (0.0, 0.0, 10.0), kind="cable", placement="front"),
        thing(2, (3.0, 0.0, 10.0), kind="glove", placement="space"),
    ]
    truth, confirmed = [], []
    for k in range(200):
        showing = frozenset(int(i) for i in (1, 2) if rng.random() < 0.3)
        truth.append(FrameTruth("t", k * PERIOD_NS, ORIGIN, showing, bool(rng.random() < 0.4)))
        confirmed.append(
            [
                sample(int(i), (i, 0.0, 10.0), bool(rng.random() < 0.5))
                for i in range(rng.integers(3))
            ]
        )
    metrics = object_metrics(truth, confirmed, objects, rules=MatchRules(min_view_s=0.0))
    by_objects = [any(s.in_view for s in c) for c in confirmed]
    by_frame = [t.frame_flagged for t in truth]
    positive = [bool(t.showing) for t in truth]
    normal_objects = sum(o for o, p in zip(by_objects, positive, strict=True) if not p)
    normal_frame = sum(f for f, p in zip(by_frame, positive, strict=True) if not p)
    assert metrics.normal_frames == positive.count(False)
    assert metrics.positive_frames == positive.count(True)
    assert (metrics.normal_by_objects, metrics.normal_by_frame) == (normal_objects, normal_frame)
    assert metrics.normal_frames_flagged_ratio == pytest.approx(normal_objects / normal_frame)
    data = metrics.as_dict()
    hits_objects = sum(o for o, p in zip(by_objects, positive, strict=True) if p)
    hits_frame = sum(f for f, p in zip(by_frame, positive, strict=True) if p)
    assert data["frame_level"]["objects"]["recall"] == pytest.approx(hits_objects / sum(positive))
    assert data["frame_level"]["frame"]["recall"] == pytest.approx(hits_frame / sum(positive))
    # Per type: the frames where a cable shows.
    cable = [1 in t.showing for t in truth]
    row = data["per_type"]["cable"]
    assert row["positive_frames"] == sum(cable)
    expected = sum(o for o, c in zip(by_objects, cable, strict=True) if c) / sum(cable)
    assert row["frame_recall_objects"] == pytest.approx(expected)
    assert data["per_placement"]["space"]["positive_frames"] == sum(2 in t.showing for t in truth)


def test_an_object_id_missing_from_the_table_is_refused():
    truth = frames("a", 3, {0: (5,)})
    with pytest.raises(ValueError, match=r"objects \[5\]"):
        object_metrics(truth, [[] for _ in truth], [thing(1, (0, 0, 1))])


# ------------------------------------------------------------------ trajectories
def test_without_a_trajectory_column_trajectories_start_where_the_stamps_jump_or_go_back():
    stamps = [0, 100, 200, 300, 1300, 1400, 1500, 200, 300, 400]
    headers = tuple(FrameHeader(i, "val" if i < 8 else "test") for i in range(len(stamps)))
    source = FrameSource(None, "bag", "x", None, None, headers)
    keys = trajectory_keys(source, list(range(len(stamps))), stamps)
    assert keys == ["val/0"] * 4 + ["val/1"] * 3 + ["val/2"] + ["test/3"] * 2
