"""benchmarks.metrics_update: its synthetic maps are what it says, and it reports figures."""

import json

import numpy as np

from benchmarks.metrics_update import main, synthetic_frame


def test_synthetic_maps_tie_most_normal_pixels_near_one_value():
    score, mask = synthetic_frame(np.random.default_rng(1), (320, 180))
    assert score.dtype == np.float32 and score.shape == mask.shape == (180, 320)
    normal = score[mask != 2]
    # Upscaled from a map 70 % at 1.0 in patches: most normal pixels stay at 1.0.
    assert np.mean(normal == 1.0) > 0.5
    assert np.unique(score).size > 0.1 * score.size


def test_benchmark_reports_times_memory_and_exact_metrics(tmp_path, capsys):
    out = tmp_path / "report.json"
    assert main(["--frames", "3", "--width", "64", "--height", "48", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["frames"] == 3 and report["exact"] is True
    assert report["peak_bytes"] >= report["pooled_bytes"] > 0
    assert report["update_ms"]["exact"]["median"] >= 0
    assert set(report["error_bounds"].values()) == {0.0}
    assert "accumulator peak" in capsys.readouterr().out
