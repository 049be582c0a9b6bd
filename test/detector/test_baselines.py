"""RXD and PAD baselines against independent implementations."""

import numpy as np
import pytest

from allo_mrad_ros.detector import MradParams, detect_pad, detect_rxd
from allo_mrad_ros.detector.score import cross_score, rx_score


def test_rx_score_matches_spectral_python():
    # The peer oracle has no rosdep key: `make test` installs it (requirements-dev.txt).
    spectral = pytest.importorskip(
        "spectral", reason="Spectral Python (pip: spectral) is not installed"
    )
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    image[10:14, 10:14] = (250, 10, 10)
    expected = spectral.rx(image.astype(np.float64))
    # Without regularisation the two are the same statistic.
    np.testing.assert_allclose(rx_score(image, 1e-12, 0.0), expected, rtol=1e-4, atol=1e-3)


def test_rxd_flags_an_outlier_colour_patch():
    rng = np.random.default_rng(1)
    image = rng.normal(100, 5, (60, 80, 3)).clip(0, 255).astype(np.uint8)
    image[20:30, 30:40] = (250, 20, 20)
    # The mask's area decides here: the contrast rule's operating point is MRAD's, and RXD's
    # whole-image covariance takes in a patch this large (2 % of the image), which then
    # stands out only 4.9 times from the image's own tail.
    result = detect_rxd(image, None, MradParams(score_ref=255.0, frame_rule="area"))
    assert result.anomalous
    assert result.mask[20:30, 30:40].all()
    assert np.count_nonzero(result.mask) < 2 * 100


def test_pad_is_the_single_cell_cross_score_thresholded():
    rng = np.random.default_rng(2)
    reference = rng.normal(100, 5, (60, 80, 3)).clip(0, 255).astype(np.uint8)
    query = reference.copy()
    query[20:30, 30:40] = (20, 220, 40)
    params = MradParams(score_ref=500.0, min_score=30.0)
    result = detect_pad(query, reference, params)
    raw = cross_score(query, reference, 1, params.abs_floor, params.rel_floor)
    expected = np.clip(255 * np.maximum(raw, 0) / 500.0, 0, 255)
    np.testing.assert_allclose(result.score, expected, rtol=1e-6)
    np.testing.assert_array_equal(result.mask > 0, expected >= 30.0)
    assert result.anomalous and result.mask[20:30, 30:40].all()
