"""Tests of the generator's settings, presets and pose draws."""

from __future__ import annotations

import math

import numpy as np
import pytest

from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.synth.config import (
    PRESETS,
    RealismConfig,
    SplitSpec,
    SynthConfig,
    SynthError,
    preset,
)
from allo_mrad_ros.synth.objects import ANOMALY_TYPES
from allo_mrad_ros.synth.planning import plan_frames
from allo_mrad_ros.synth.poses import perturb, pose_error


def test_presets_are_valid():
    for name in PRESETS:
        config = preset(name)
        assert config.name == name and config.frames > 0
    smoke, demo, bench = preset("smoke"), preset("demo"), preset("bench")
    assert smoke.width * smoke.height <= 320 * 180
    assert (demo.width, demo.height) == (bench.width, bench.height) == (1920, 1080)
    assert 35 <= demo.frames <= 45
    assert set(bench.splits) == {"train", "val", "test"}
    assert bench.splits["train"].anomalous == 0
    test = bench.splits["test"]
    assert test.frames >= 300 and 1.8 <= test.anomalous / test.normal <= 2.2
    plans = plan_frames(bench, 0)
    kinds = [p.anomaly for p in plans if p.split == "test" and p.anomaly]
    counts = np.unique(kinds, return_counts=True)[1]
    assert len(counts) == len(ANOMALY_TYPES) and counts.max() - counts.min() <= 1
    with pytest.raises(SynthError):
        preset("huge")


@pytest.mark.parametrize(
    "change",
    [
        {"width": 8},
        {"position_sigma_m": -1.0},
        {"rotation_sigma_rad": math.nan},
        {"depths_m": ()},
        {"days": (0, 10)},
        {"sun_weights": (1.0,)},
        {"anomaly_types": ("spoon",)},
        {"splits": {"dev": SplitSpec(1, 0, 1)}},
        {"realism": "yes"},
        {"png_compression": 12},
    ],
)
def test_config_validation(change):
    with pytest.raises(SynthError):
        preset("smoke").with_overrides(**change)


def test_config_helpers():
    with pytest.raises(SynthError):
        SplitSpec(0, 0, 1)
    with pytest.raises(SynthError):
        RealismConfig(vignetting=2.0)
    with pytest.raises(SynthError):
        preset("smoke").with_overrides(colour="red")
    scaled = preset("bench").with_frames(51)
    assert 49 <= scaled.frames <= 53 and scaled.splits["train"].anomalous == 0
    assert isinstance(SynthConfig(name="x", splits={"test": SplitSpec(1, 1, 1)}), SynthConfig)


def test_perturbation_and_pose_error_statistics():
    rng = np.random.default_rng(0)
    base = look_at([10.0, -20.0, 5.0], [0.0, 0.0, 0.0])
    moved = np.array([perturb(base, rng, 1.0, 0.2)[:3, 3] for _ in range(2000)])
    assert np.allclose(moved.std(axis=0), 1.0, atol=0.08)
    errors = [pose_error(base, rng, 0.02, 0.0035) for _ in range(500)]
    assert np.allclose(np.std([e[:3, 3] - base[:3, 3] for e in errors], axis=0), 0.02, atol=0.003)
    assert np.array_equal(pose_error(base, rng, 0.0, 0.0), base)
