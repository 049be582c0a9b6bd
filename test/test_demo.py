"""The demo's live row is computed as the offline one: the node's score map and its image
score (``~/result``), never the mask's area (no ROS needed)."""

import types

import numpy as np

from allo_mrad_ros.demo import (
    DemoPaths,
    LiveTally,
    build_report,
    missing_reason,
    node_figures,
    node_line,
    print_summary,
)
from allo_mrad_ros.metrics import MetricsAccumulator


class FakeSequence:
    """Four 4x4 frames: two normal, two with an anomaly (class 2) in the top-left pixel."""

    def __init__(self):
        self.frames = [
            types.SimpleNamespace(stamp_ns=stamp, name=f"f{stamp}", is_anomalous=stamp >= 2)
            for stamp in range(4)
        ]

    def load_mask(self, frame):
        mask = np.ones((4, 4), np.uint8)
        if frame.is_anomalous:
            mask[0, 0] = 2
        return mask

    def load_image(self, frame):
        return np.zeros((4, 4, 3), np.uint8)


def _recorded(stamp, image_score, mask_pixels):
    score = np.full((4, 4), 10.0, np.float32)
    score[0, 0] = 200.0 if stamp >= 2 else 20.0
    mask = np.zeros((4, 4), np.uint8)
    mask.flat[:mask_pixels] = 255
    return types.SimpleNamespace(
        stamp_ns=stamp, score=score, mask=mask, image_score=image_score, latency_ms=5.0
    )


# The image scores rank the anomalous frames first; the mask areas rank them last.
FRAMES = [_recorded(0, 1.0, 9), _recorded(1, 2.0, 8), _recorded(2, 3.0, 1), _recorded(3, 4.0, 0)]


def test_live_i_auroc_ranks_the_node_image_score_not_the_mask_area(tmp_path):
    tally = LiveTally(FakeSequence(), tmp_path, max_overlays=0)
    for recorded in FRAMES:
        tally.add(recorded)
    assert tally.frames == 4 and tally.missing() == []
    assert tally.metrics()["i_auroc"] == 1.0  # by mask area it would be 0.0


def test_live_row_equals_the_offline_computation_on_the_same_outputs(tmp_path):
    sequence = FakeSequence()
    tally = LiveTally(sequence, tmp_path, max_overlays=0)
    offline = MetricsAccumulator()
    for recorded, frame in zip(FRAMES, sequence.frames, strict=True):
        tally.add(recorded)
        offline.update(recorded.score, recorded.image_score, sequence.load_mask(frame))
    assert tally.metrics() == offline.compute().as_dict()


def test_outputs_of_frames_outside_the_sequence_are_ignored(tmp_path):
    tally = LiveTally(FakeSequence(), tmp_path)
    tally.add(_recorded(99, 1.0, 0))
    assert tally.frames == 0 and tally.overlays == []
    assert tally.missing() == ["f0", "f1", "f2", "f3"]


NODE_STATUS = {
    "input_age_taken_ms_p50": "8.5",
    "input_age_taken_ms_p95": "21.0",
    "input_age_published_ms_p50": "41.5",
    "input_age_published_ms_p95": "90.25",
    "frames_received": "40",
    "frames_processed": "31",
    "frames_dropped_stale": "6",
    "frames_dropped_too_old": "3",
    "rate_hz": "12.00",
}


def test_the_report_carries_the_node_s_own_input_ages_beside_the_recorder_s_latency(
    tmp_path, capsys
):
    tally = LiveTally(FakeSequence(), tmp_path, max_overlays=0)
    for recorded in FRAMES:
        tally.add(recorded)
    offline = {"frames": 4, "methods": {}}
    report = build_report(tally, offline, NODE_STATUS)
    assert report["latency_ms_p50"] == 5.0  # the recorder's
    assert report["node"] == {
        "input_age_taken_ms_p50": 8.5,
        "input_age_taken_ms_p95": 21.0,
        "input_age_published_ms_p50": 41.5,
        "input_age_published_ms_p95": 90.25,
        "frames_received": 40,
        "frames_processed": 31,
        "frames_dropped_stale": 6,
        "frames_dropped_too_old": 3,
    }
    print_summary(DemoPaths(tmp_path, tmp_path), report)
    printed = capsys.readouterr().out
    assert "latency input published -> outputs received: p50 5 ms" in printed
    assert (
        "node (its /diagnostics): age since the image was published when taken p50 8 ms, "
        "p95 21 ms; when its outputs were published p50 42 ms, p95 90 ms; 31 of 40 images "
        "received processed, 3 dropped as older than max_input_age_s, 6 replaced"
    ) in printed


def test_a_node_that_processed_nothing_has_no_ages_and_says_so(tmp_path):
    figures = node_figures({"frames_received": "5", "frames_processed": "0"})
    assert figures["input_age_published_ms_p50"] is None
    assert figures["frames_dropped_too_old"] == 0 and figures["frames_received"] == 5
    assert node_figures({})["frames_processed"] is None  # no status received at all
    report = build_report(LiveTally(FakeSequence(), tmp_path), {}, {})
    assert "no input-age figures" in node_line(report)


def test_frames_missing_from_the_live_row_are_blamed_on_whoever_lost_them(tmp_path):
    tally = LiveTally(FakeSequence(), tmp_path, max_overlays=0)
    for recorded in FRAMES[:2]:
        tally.add(recorded)
    # The node processed all four; this recorder got the outputs of two.
    report = build_report(tally, {}, {**NODE_STATUS, "frames_processed": "4"})
    assert missing_reason(report) == (
        "the node processed 4 frames: this recorder, short of CPU itself, missed the outputs of 2"
    )
    # The node processed two: it dropped the others.
    report = build_report(tally, {}, {**NODE_STATUS, "frames_processed": "2"})
    assert "the node keeps the newest image" in missing_reason(report)
    assert "the node keeps the newest image" in missing_reason(build_report(tally, {}, {}))
