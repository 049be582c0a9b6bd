"""The false-score probe: its kinds of pixel partition the non-anomaly pixels; a run adds up."""

import numpy as np

from allo_mrad_ros.synth.config import preset
from allo_mrad_ros.synth.generator import generate
from benchmarks.false_scores import KINDS, pixel_kinds, probe


def test_kinds_partition_the_pixels_that_are_not_anomalies():
    rng = np.random.default_rng(0)
    mask = rng.choice(np.array([0, 1, 2], np.uint8), size=(30, 40), p=[0.5, 0.4, 0.1])
    kinds = pixel_kinds(mask, rng.uniform(0, 255, mask.shape))
    stacked = np.stack([kinds[k] for k in KINDS])
    assert stacked.sum(axis=0).max() == 1 or not stacked.any()
    assert np.array_equal(stacked.any(axis=0), mask != 2)


def test_the_edge_band_is_two_pixels_either_side_of_the_silhouette():
    mask = np.zeros((40, 40), np.uint8)
    mask[10:30, 10:30] = 1
    kinds = pixel_kinds(mask, np.full(mask.shape, 100.0))
    assert np.count_nonzero(kinds["edge"]) == 24 * 24 - 16 * 16
    assert np.count_nonzero(kinds["mid"]) == 16 * 16 and not kinds["dark"].any()


def test_a_run_counts_every_pixel_once(tmp_path):
    config = preset("smoke").with_frames(3)
    generate(config, tmp_path / "seq", 2, progress=False)
    report = probe(tmp_path / "seq")
    frames = config.splits["test"].frames
    assert report["frames"] <= frames
    anomaly_free = sum(report["pixels"].values())
    assert frames * config.width * config.height - anomaly_free > 0  # the anomaly pixels
    for row in report["methods"].values():
        for measure in ("flagged", "above_median_anomaly"):
            assert set(row[measure]) == set(KINDS)
            for kind, share in row[measure].items():
                # No share for a kind without pixels (the smoke frames have no bright ones).
                assert (share is None) == (report["pixels"][kind] == 0)
                assert share is None or 0.0 <= share <= 1.0
