"""The ALLO metrics against scikit-learn and hand-computed cases."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from sklearn.metrics import (
    auc,
    average_precision_score,
    precision_recall_curve,
    roc_auc_score,
    roc_curve,
)

from allo_mrad_ros.metrics import (
    MetricsAccumulator,
    MetricsError,
    PixelScoreHistogram,
    aupr_trapezoid,
    auroc_from_curve,
    average_precision,
    average_precision_from_curve,
    bootstrap_ap_difference,
    fpr_at_tpr,
    fpr_at_tpr_from_curve,
    fpr_at_tpr_interpolated,
    frame_counts,
    roc_auc,
)


def sklearn_fpr95(labels, scores):
    # Keep every threshold: the default drop_intermediate=True thins collinear points, and
    # "the first point reaching TPR 0.95" can then fall on a later point with a higher FPR.
    fpr, tpr, _ = roc_curve(labels, scores, drop_intermediate=False)
    return fpr[np.argmax(tpr >= 0.95)]


def _random_scores(seed: int, n: int, ties: bool) -> tuple[np.ndarray, np.ndarray]:
    """Scores that separate two classes partly, both classes present, optionally tied."""
    rng = np.random.default_rng(seed)
    labels = rng.random(n) < rng.uniform(0.05, 0.95)
    if labels.all() or not labels.any():
        labels[0] = not labels[0]
    scores = rng.normal(size=n) + labels * rng.uniform(0, 2)
    if ties:
        scores = np.round(scores * 2) / 2
    return scores, labels


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 400), ties=st.booleans())
@example(seed=6838, n=121, ties=True)  # found on a fresh clone: sklearn's thinned ROC curve
def test_exact_metrics_match_sklearn(seed, n, ties):
    scores, labels = _random_scores(seed, n, ties)
    assert roc_auc(scores, labels) == pytest.approx(roc_auc_score(labels, scores), abs=1e-12)
    assert average_precision(scores, labels) == pytest.approx(
        average_precision_score(labels, scores), abs=1e-12
    )
    assert fpr_at_tpr(scores, labels) == pytest.approx(sklearn_fpr95(labels, scores), abs=1e-12)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 400), ties=st.booleans())
def test_trapezoid_aupr_and_interpolated_fpr95_match_sklearn(seed, n, ties):
    scores, labels = _random_scores(seed, n, ties)
    precision, recall, _ = precision_recall_curve(labels, scores)
    assert aupr_trapezoid(scores, labels) == pytest.approx(auc(recall, precision), abs=1e-12)
    fpr, tpr, _ = roc_curve(labels, scores, drop_intermediate=False)
    # The last operating point below the target and the first reaching it.
    below = np.flatnonzero(tpr < 0.95)[-1]
    expected = np.interp(0.95, tpr[below : below + 2], fpr[below : below + 2])
    assert fpr_at_tpr_interpolated(scores, labels) == pytest.approx(expected, abs=1e-12)


def test_step_ap_and_trapezoid_aupr_differ_on_tied_maps():
    # One positive ranked first, then a block of 50 ties holding 9 positives and 41
    # negatives: the step AP credits the block's recall at its end precision, the
    # trapezoid draws a straight line across the block.
    scores = np.r_[1.0, np.zeros(50)]
    labels = np.r_[True, np.ones(9, bool), np.zeros(41, bool)]
    step = 0.1 * 1.0 + 0.9 * (10 / 51)
    trapezoid = 0.1 * 1.0 + 0.9 * (1.0 + 10 / 51) / 2
    assert average_precision(scores, labels) == pytest.approx(step)
    assert aupr_trapezoid(scores, labels) == pytest.approx(trapezoid)
    assert aupr_trapezoid(scores, labels) - average_precision(scores, labels) > 0.35


def test_interpolated_fpr95_hand_computed():
    # 20 positives: TPR 0.90 at FPR 0, then a tie block of 2 positives and 10 negatives
    # takes TPR to 1.0 at FPR 1.0. First-threshold FPR95 = 1.0; interpolated = 0.5.
    scores = np.r_[np.arange(2.0, 20.0), np.zeros(12)]
    labels = np.r_[np.ones(20, bool), np.zeros(10, bool)]
    assert fpr_at_tpr(scores, labels) == pytest.approx(1.0)
    assert fpr_at_tpr_interpolated(scores, labels) == pytest.approx(0.5)


def test_fpr95_hand_computed():
    # 20 positives scored 20..39 (one weak positive at 0.5), 10 negatives at 0..9 and one at 25.
    positives = np.r_[np.arange(21.0, 40.0), 0.5]
    negatives = np.r_[np.arange(0.0, 10.0), 25.0]
    scores = np.r_[positives, negatives]
    labels = np.r_[np.ones(20, bool), np.zeros(11, bool)]
    # TPR reaches 19/20 = 0.95 at threshold 21: one negative (25) is above it -> FPR 1/11.
    assert fpr_at_tpr(scores, labels) == pytest.approx(1 / 11)
    # Asking for all positives needs threshold 0.5: negatives 1..9 and 25 are above -> 10/11.
    assert fpr_at_tpr(scores, labels, 1.0) == pytest.approx(10 / 11)


def test_histogram_equals_exact_metrics_on_grid_scores():
    rng = np.random.default_rng(3)
    masks = [
        np.where(rng.random((20, 30)) < 0.1, 2, rng.integers(0, 2, (20, 30))) for _ in range(4)
    ]
    scores = [np.round(rng.random((20, 30)) * 255 * 64) / 64 + 30 * (m == 2) for m in masks]
    scores = [np.clip(s, 0, 255) for s in scores]
    histogram = PixelScoreHistogram()
    for s, m in zip(scores, masks, strict=True):
        histogram.update(s, m)
    pooled_scores = np.concatenate([s.ravel() for s in scores])
    pooled_labels = np.concatenate([(m == 2).ravel() for m in masks])
    curve = histogram.curve()
    assert auroc_from_curve(curve) == pytest.approx(roc_auc_score(pooled_labels, pooled_scores))
    assert average_precision_from_curve(curve) == pytest.approx(
        average_precision_score(pooled_labels, pooled_scores)
    )
    assert fpr_at_tpr_from_curve(curve) == pytest.approx(
        sklearn_fpr95(pooled_labels, pooled_scores)
    )


def test_accumulator_pools_frames_and_uses_area_as_image_score():
    rng = np.random.default_rng(4)
    accumulator = MetricsAccumulator()
    image_scores, image_labels = [], []
    for index in range(6):
        mask = np.ones((10, 10), np.uint8)
        if index % 2:
            mask[2:5, 2:5] = 2
        score = rng.random((10, 10)) * 100 + 100 * (mask == 2)
        area = float(np.count_nonzero(score > 150))
        accumulator.update(score, area, mask)
        image_scores.append(area)
        image_labels.append(bool(index % 2))
    metrics = accumulator.compute()
    assert metrics.i_auroc == pytest.approx(roc_auc_score(image_labels, image_scores))
    assert 0.9 < metrics.p_auroc <= 1.0 and 0.0 <= metrics.p_fpr95 <= 1.0
    assert set(metrics.as_dict()) == {
        "i_auroc",
        "p_auroc",
        "p_ap",
        "p_fpr95",
        "p_aupr",
        "p_fpr95_interp",
    }
    assert metrics.p_fpr95_interp <= metrics.p_fpr95


def test_single_class_is_an_error_or_nan():
    with pytest.raises(MetricsError, match="need both classes"):
        roc_auc(np.arange(5.0), np.zeros(5, bool))
    accumulator = MetricsAccumulator()
    accumulator.update(np.zeros((4, 4)), 0.0, np.ones((4, 4), np.uint8))
    assert np.isnan(accumulator.compute().p_ap)


def test_bad_inputs_are_named():
    with pytest.raises(MetricsError, match="3 scores but 2 labels"):
        roc_auc(np.arange(3.0), np.array([True, False]))
    with pytest.raises(MetricsError, match="NaN or Inf"):
        PixelScoreHistogram().update(np.full((2, 2), np.nan), np.zeros((2, 2)))
    with pytest.raises(MetricsError, match="differ in shape"):
        PixelScoreHistogram().update(np.zeros((2, 2)), np.zeros((2, 3)))


def _frames(rng, count, shape=(12, 16)):
    scores = [rng.uniform(0, 255, shape).round(1) for _ in range(count)]
    masks = [np.where(rng.random(shape) < 0.2, 2, 0).astype(np.uint8) for _ in range(count)]
    return scores, masks


def test_bootstrap_resample_equals_sklearn_on_the_same_frames():
    rng = np.random.default_rng(3)
    scores, masks = _frames(rng, 7)
    noisy = [s + rng.normal(0, 30, s.shape) for s in scores]
    noisy = [np.clip(n, 0, 255) for n in noisy]
    counts_a = np.stack(
        [frame_counts(s, m, bins_per_unit=1) for s, m in zip(scores, masks, strict=True)]
    )
    counts_b = np.stack(
        [frame_counts(s, m, bins_per_unit=1) for s, m in zip(noisy, masks, strict=True)]
    )
    differences = bootstrap_ap_difference(counts_a, counts_b, resamples=3, seed=11)

    # Replay the first resample's frame draw and score the repeated pixels with sklearn.
    drawn = np.random.default_rng(11).integers(0, 7, 7)
    labels = np.concatenate([(masks[i] == 2).ravel() for i in drawn])

    def ap(maps):
        return average_precision_score(
            labels, np.concatenate([np.rint(maps[i]).ravel() for i in drawn])
        )

    assert differences.shape == (3,)
    assert differences[0] == pytest.approx(ap(noisy) - ap(scores), abs=1e-12)
    assert not np.allclose(differences, 0.0)


def test_bootstrap_of_a_detector_against_itself_is_zero():
    rng = np.random.default_rng(4)
    scores, masks = _frames(rng, 5)
    counts = np.stack([frame_counts(s, m) for s, m in zip(scores, masks, strict=True)])
    assert np.array_equal(bootstrap_ap_difference(counts, counts, resamples=20), np.zeros(20))


def test_bootstrap_rejects_unpaired_counts():
    counts = np.zeros((4, 2, 511), dtype=np.int32)
    with pytest.raises(MetricsError, match="frames, 2, bins"):
        bootstrap_ap_difference(counts, counts[:3])
    with pytest.raises(MetricsError, match="resamples"):
        bootstrap_ap_difference(counts, counts, resamples=0)
