"""bench-node's bookkeeping: renders per frame from the node's counters, the feed plan."""

import numpy as np
import pytest

pytest.importorskip("rclpy")

from benchmarks import node as bench


def test_renders_per_frame_from_the_counters_and_n_a_without_them():
    before = {"frames_processed": 10, "references_rendered": 10, "references_reused": 0}
    after = {"frames_processed": 110, "references_rendered": 35, "references_reused": 75}
    assert bench.renders_per_frame(before, after) == 0.25
    # A node that does not count its renders (no reference reuse): n/a, not 0 or 1.
    assert bench.renders_per_frame({"frames_processed": 1}, {"frames_processed": 9}) is None
    assert bench.renders_per_frame(before, before) is None  # nothing processed


def test_the_feed_plan_plays_the_moving_segment_back_and_forth():
    poses = [np.eye(4) for _ in range(4)]
    for k, pose in enumerate(poses):
        pose[0, 3] = 0.005 * k
    images = [np.full((2, 2, 3), k, np.uint8) for k in range(4)]
    plan = bench.FeedPlan("moving", poses, images, 30.0)
    assert [plan.frame(i) for i in range(8)] == [0, 1, 2, 3, 2, 1, 0, 1]
    motion = plan.motion()
    assert motion["segment_frames"] == 4 and motion["segment_s"] == pytest.approx(0.1)
    assert motion["linear_m_s_max"] == pytest.approx(0.15)
    still = bench.FeedPlan("still", [np.eye(4)] * 2, images[:2], 30.0)
    assert [still.frame(i) for i in range(4)] == [0, 1, 0, 1]
    assert still.motion()["linear_m_s_max"] == 0.0


def test_the_summary_line_says_n_a_for_unknown_renders():
    report = {
        "trajectory": "moving",
        "pipelined": True,
        "fps": 29.6,
        "frames_dropped": 3,
        "frames_published": 1003,
        "renders_per_frame": None,
        "latency_ms_p50": 30.0,
        "latency_ms_p95": 45.0,
        "latency_ms_p99": 50.0,
        "cpu_s_per_frame": 0.02,
        "rss_mb_after_1000": 400.0,
        "rss_growth_percent": 1.0,
        "load_average_before": [1.0, 0, 0],
        "load_average_after": [2.0, 0, 0],
    }
    assert " n/a " in bench.summary_line("1080p30", report)
    report["renders_per_frame"] = 0.2
    assert " 0.20 " in bench.summary_line("1080p30", report)


def test_the_node_s_stage_figures_are_read_from_its_diagnostics_values():
    values = {
        "latency_middleware_ms_p50": "4.0",
        "latency_middleware_ms_p95": "9.5",
        "latency_detect_ms_p50": "14.0",
        "latency_detect_ms_p95": "30.0",
        "input_age_taken_ms_p50": "8.0",
        "input_age_taken_ms_p95": "20.0",
        "input_age_published_ms_p50": "30.0",
        "input_age_published_ms_p95": "61.0",
        "latency_slot_ms_p50": "n/a",  # unreadable: left out
        "frames_processed": "10",
    }
    assert bench.node_stages(values) == {
        "middleware": {"p50": 4.0, "p95": 9.5},
        "detect": {"p50": 14.0, "p95": 30.0},
        "age_taken": {"p50": 8.0, "p95": 20.0},
        "age_published": {"p50": 30.0, "p95": 61.0},
    }
    assert bench.node_stages({}) == {}


def test_the_latency_is_split_into_windows_of_image_stamps():
    # Stamps every second for 70 s; latency 10 ms in the first 30 s, then 20, then 40.
    arrivals = {}
    for second in range(70):
        latency_s = 0.010 if second < 30 else 0.020 if second < 60 else 0.040
        arrivals[(1000 + second) * 10**9] = 1000 + second + latency_s
    windows = bench.latency_windows(arrivals, window_s=30.0)
    assert [w["start_s"] for w in windows] == [0.0, 30.0, 60.0]
    assert [w["frames"] for w in windows] == [30, 30, 10]
    assert [round(w["p50"], 6) for w in windows] == [10.0, 20.0, 40.0]
    assert bench.latency_windows({}) == []
