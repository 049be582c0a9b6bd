"""The array-backend comparison of `make bench-detector`, on a small scene."""

import importlib.util

import numpy as np

from allo_mrad_ros.detector import MradParams
from benchmarks.detector import compare_backends


def test_backends_are_timed_and_compared_with_numpy_and_an_unrunnable_one_says_why():
    rng = np.random.default_rng(0)
    reference = rng.integers(0, 256, (68, 120, 3), dtype=np.uint8)
    query = np.repeat(np.repeat(reference, 2, axis=0), 2, axis=1)
    query[40:60, 100:130] = (250, 20, 20)
    specs = ["numpy", "torch:cpu", "no-such-backend"]
    figures = compare_backends(query, reference, MradParams(process_scale=0.5), specs, 2)
    assert figures["numpy"]["max_abs_raw_diff_vs_numpy"] == 0.0
    assert figures["numpy"]["mask_pixels_differing"] == 0
    assert figures["numpy"]["detect_ms_median"] > 0
    assert "array_backend must be one of" in figures["no-such-backend"]["unavailable"]
    if importlib.util.find_spec("torch") is None:
        assert "needs PyTorch" in figures["torch:cpu"]["unavailable"]
    else:
        torch_figures = figures["torch:cpu"]
        assert torch_figures["max_abs_raw_diff_vs_numpy"] <= 1e-5 * torch_figures["max_raw_score"]
        assert torch_figures["cross_score_ms_median"] > 0
