"""``allo-bag evaluate --objects`` end to end on a tiny generated sequence with trajectories
and ground-truth objects: the report's frame counts against the sequence's own instance
masks, the trajectories from its ``trajectory`` column, and options that do not apply."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from allo_mrad_ros.evaluation.objects import (
    ObjectEvaluationError,
    detect_frames,
    score_run,
    track,
)
from allo_mrad_ros.evaluation.sources import open_sequence
from allo_mrad_ros.objects import ObjectParams
from allo_mrad_ros.sequence import read_sequence
from allo_mrad_ros.synth.config import SplitSpec, preset
from allo_mrad_ros.synth.generator import generate
from rosbag_tools.cli import main


@pytest.fixture(scope="module")
def sequence_root(tmp_path_factory):
    base = preset("objects")
    config = base.with_overrides(
        width=96,
        height=64,
        splits={"test": SplitSpec(3, 2, 5)},
        trajectory=replace(base.trajectory, frames=8),
    )
    root = tmp_path_factory.mktemp("objects") / "seq"
    generate(config, root, 5, progress=False)
    return root


@pytest.fixture(scope="module")
def run(sequence_root):
    return detect_frames(sequence_root, split="test", progress=False)


def test_frames_are_grouped_by_the_trajectory_column_and_know_which_objects_show(
    sequence_root, run
):
    sequence = read_sequence(sequence_root)
    frames = [f for f in sequence.frames if f.split == "test"]
    assert [f.trajectory for f in run.frames] == [f"test/{f.extra['trajectory']}" for f in frames]
    for frame, detected in zip(frames, run.frames, strict=True):
        instances = sequence.load_instances(frame)
        assert detected.showing == {int(v) for v in np.unique(instances) if v}
        assert detected.stamp_ns == frame.stamp_ns


def test_the_tracker_starts_afresh_at_each_trajectory(run):
    confirmed, timings = track(
        run, ObjectParams(confirm_hits=1, confirm_window=1, parallax_sigma=0)
    )
    assert len(confirmed) == len(timings) == len(run.frames)
    ids_of = {}
    for frame, samples in zip(run.frames, confirmed, strict=True):
        for sample in samples:
            ids_of.setdefault(sample.id, set()).add(frame.trajectory)
    assert all(len(trajectories) == 1 for trajectories in ids_of.values())


def test_evaluate_objects_writes_the_report_with_counts_from_the_instance_masks(
    sequence_root, run, tmp_path, capsys
):
    out = tmp_path / "report"
    assert main(["evaluate", str(sequence_root), "--objects", "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "| recall |" in printed and str(out) in printed
    report = json.loads((out / "objects.json").read_text())
    showing = [bool(f.showing) for f in run.frames]
    assert report["frames"] == len(run.frames)
    assert report["frame_level"]["positive_frames"] == sum(showing)
    assert report["frame_level"]["normal_frames"] == showing.count(False)
    flagged_normal = sum(f.frame_flagged for f in run.frames if not f.showing)
    assert report["frame_level"]["frame"]["normal_flagged"] == flagged_normal
    metrics, _ = score_run(run, ObjectParams())
    assert report["recall"] == metrics.recall and report["precision"] == metrics.precision
    assert (out / "objects.md").read_text().startswith("# Objects")


def test_tracker_parameters_are_taken_and_checked(sequence_root, tmp_path, capsys):
    out = tmp_path / "report"
    argv = ["evaluate", str(sequence_root), "--objects", "--out", str(out), "--quiet"]
    assert main([*argv, "--object-set", "confirm_hits=2", "--object-set", "gate_sigma=3"]) == 0
    params = json.loads((out / "objects.json").read_text())["params"]
    assert (params["confirm_hits"], params["gate_sigma"]) == (2, 3.0)
    for bad, message in (
        (["--object-set", "confirm_hits=9"], "confirm_hits"),
        (["--object-set", "nonsense=1"], "nonsense"),
        (["--object-set", "gate_sigma"], "NAME=VALUE"),
        (["--limit", "3"], "--limit"),
    ):
        with pytest.raises(SystemExit) as exit_info:
            main([*argv, "--overwrite", *bad])
        assert exit_info.value.code == 2
        assert message in capsys.readouterr().err


def test_an_input_without_ground_truth_objects_is_refused(tmp_path):
    from rosbag_fixtures import write_tiny_sequence

    root = write_tiny_sequence(tmp_path / "plain")
    with pytest.raises(ObjectEvaluationError, match="no ground-truth objects"):
        detect_frames(open_sequence(root), progress=False)


def test_a_bag_of_the_sequence_gives_the_same_trajectories_and_metrics(
    sequence_root, run, tmp_path
):
    from rosbag_tools.bag_source import open_source
    from rosbag_tools.writer import write_bag

    bag = tmp_path / "bag"
    write_bag(sequence_root, bag)
    from_bag = detect_frames(open_source(bag), split="test", progress=False)
    # The bag has no trajectory column: its trajectories are found from the stamps' gaps,
    # and must split the frames where the sequence's column does.
    assert len(from_bag.frames) == len(run.frames)

    def boundaries(frames):
        return [
            k for k in range(1, len(frames)) if frames[k].trajectory != frames[k - 1].trajectory
        ]

    assert boundaries(from_bag.frames) == boundaries(run.frames)
    assert [f.showing for f in from_bag.frames] == [f.showing for f in run.frames]
    params = ObjectParams(confirm_hits=2, confirm_window=3, parallax_sigma=0)
    bag_metrics, _ = score_run(from_bag, params)
    sequence_metrics, _ = score_run(run, params)
    assert bag_metrics.as_dict() == sequence_metrics.as_dict()
