"""The frame-decision benchmark: sequence names, the threshold it chooses, and that a cached
frame is decided as ``detect`` decided it."""

import argparse
from pathlib import Path

import numpy as np
import pytest

from allo_mrad_ros.detector import detect, profile
from allo_mrad_ros.example_scene import example_pair
from benchmarks.decision import decide_all, lowest_threshold
from benchmarks.decision_cache import CachedFrame, SequenceSplit, load_frame, save_frame


@pytest.mark.parametrize(
    ("text", "path", "split", "change", "label"),
    [
        ("data/bench:test", "data/bench", "test", None, "bench:test"),
        ("data/demo/sequence", "data/demo/sequence", None, None, "demo"),
        ("data/bench_val:val@agx", "data/bench_val", "val", "agx", "bench_val:val@agx"),
        ("data/objects:val@ramp#240", "data/objects", "val", "ramp", "objects:val@ramp#240"),
    ],
)
def test_sequence_names(text, path, split, change, label):
    item = SequenceSplit.parse(text)
    assert (item.path, item.split, item.perturbation) == (Path(path), split, change)
    assert item.label == label
    assert item.limit == (240 if "#" in text else None)


@pytest.mark.parametrize("text", ["data/bench:test#0", "data/bench:test#many"])
def test_a_bad_frame_count_is_refused(text):
    with pytest.raises(argparse.ArgumentTypeError, match="frame count"):
        SequenceSplit.parse(text)


def test_an_unknown_query_change_is_refused_by_name():
    with pytest.raises(argparse.ArgumentTypeError, match="'sepia'"):
        SequenceSplit.parse("data/bench:test@sepia")


def test_the_threshold_flags_at_most_the_target_on_every_sequence():
    rng = np.random.default_rng(0)
    normal = [rng.gamma(2.0, 1.0, 40), rng.gamma(2.0, 2.0, 100)]
    threshold = lowest_threshold(normal, 0.05)
    assert all((values > threshold).mean() <= 0.05 for values in normal)
    # The lowest such: a tenth less flags more than the target somewhere.
    assert any((values > threshold - 0.1).mean() > 0.05 for values in normal)
    assert round(threshold * 10) == pytest.approx(threshold * 10)


@pytest.mark.parametrize("rule", ["contrast", "area"])
def test_a_cached_frame_is_decided_as_detect_decided_it(tmp_path, rule):
    pair = example_pair(270, 480, seed=3)
    params = profile("default", frame_rule=rule)
    frames = []
    results = []
    for index, query in enumerate((pair.query, pair.clean_query)):
        result = detect(query, pair.reference, params)
        path = tmp_path / f"{index}.npz"
        save_frame(path, f"frame{index}", "", index == 0, result)
        frames.append(load_frame(path))
        results.append(result)
    assert all(isinstance(frame, CachedFrame) for frame in frames)
    outcome = decide_all(frames, (270, 480), params)
    assert outcome.flagged.tolist() == [r.anomalous for r in results]
    assert outcome.scores.tolist() == [r.anomaly_score for r in results]
