"""The ALLO metrics against scikit-learn, a per-pixel oracle and hand-computed cases."""

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
    aupr_trapezoid,
    average_precision,
    bootstrap_ap_difference,
    fpr_at_tpr,
    fpr_at_tpr_interpolated,
    frame_counts,
    roc_auc,
)
from allo_mrad_ros.metrics.pixel import pixel_metrics
from allo_mrad_ros.metrics.score_counts import (
    PooledScoreCounts,
    ScoreCounts,
    merge,
    score_keys,
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
    for value in (0.0, 1.0, 0.0):  # normal frames only, pooled
        accumulator.update(np.full((4, 4), value, np.float32), 0.0, np.ones((4, 4), np.uint8))
    assert np.isnan(accumulator.compute().p_ap)
    assert accumulator.curve() is None


def test_bad_inputs_are_named():
    with pytest.raises(MetricsError, match="3 scores but 2 labels"):
        roc_auc(np.arange(3.0), np.array([True, False]))
    with pytest.raises(MetricsError, match="NaN or Inf"):
        MetricsAccumulator().update(np.full((2, 2), np.nan), 0.0, np.zeros((2, 2)))
    with pytest.raises(MetricsError, match="NaN or Inf"):
        frame_counts(np.full((2, 2), np.inf), np.zeros((2, 2)))
    with pytest.raises(MetricsError, match="differ in shape"):
        MetricsAccumulator().update(np.zeros((2, 2)), 0.0, np.zeros((2, 3)))
    with pytest.raises(MetricsError, match="max_entries"):
        MetricsAccumulator(max_entries=3)


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


# ----------------------------------------------------------------- pooled pixel metrics
def sklearn_pixel_metrics(scores, labels) -> dict[str, float]:
    """Every pixel metric by scikit-learn over every pixel apart (float64, as it casts)."""
    scores = np.asarray(scores, dtype=np.float64)
    fpr, tpr, _ = roc_curve(labels, scores, drop_intermediate=False)
    below = np.flatnonzero(tpr < 0.95)[-1]
    precision, recall, _ = precision_recall_curve(labels, scores)
    return {
        "p_auroc": roc_auc_score(labels, scores),
        "p_ap": average_precision_score(labels, scores),
        "p_aupr": auc(recall, precision),
        "p_fpr95": sklearn_fpr95(labels, scores),
        "p_fpr95_interp": np.interp(0.95, tpr[below : below + 2], fpr[below : below + 2]),
    }


def oracle_fpr95(scores, labels) -> float:
    """The definition, pixel by pixel in float64: walk the distinct scores from the highest
    down; at the first threshold whose true-positive rate reaches 95 %, the fraction of
    negatives scoring at least the threshold."""
    scores = np.asarray(scores, dtype=np.float64)
    positives, negatives = scores[labels], scores[~labels]
    for threshold in sorted(set(scores.tolist()), reverse=True):
        if np.count_nonzero(positives >= threshold) >= 0.95 * positives.size - 1e-9:
            return np.count_nonzero(negatives >= threshold) / negatives.size
    raise AssertionError("unreachable: the lowest score takes every positive")


def _pooled(frames, **options):
    accumulator = MetricsAccumulator(**options)
    for score, mask in frames:
        accumulator.update(score, 0.0, mask)
    return accumulator


def _pixels(frames):
    scores = np.concatenate([np.asarray(s).ravel() for s, _ in frames])
    labels = np.concatenate([(m == 2).ravel() for _, m in frames])
    return scores, labels


def _assert_metrics(metrics, expected, tolerance=1e-12):
    for key, value in expected.items():
        assert getattr(metrics, key) == pytest.approx(value, abs=tolerance), key


def _float_frames(seed, count, shape, ties):
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(count):
        mask = np.where(rng.random(shape) < rng.uniform(0.02, 0.5), 2, rng.integers(0, 2, shape))
        score = (rng.gamma(2.0, 3.0, shape) + 4.0 * (mask == 2)).astype(np.float32)
        if ties:
            score = np.round(score * 4) / 4
        frames.append((score, mask.astype(np.uint8)))
    frames[0][1].flat[0], frames[0][1].flat[1] = 2, 0  # both classes present
    return frames


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(1, 6),
    ties=st.booleans(),
)
def test_pooled_pixel_metrics_equal_sklearn_on_random_frames(seed, count, ties):
    frames = _float_frames(seed, count, (13, 17), ties)
    metrics = _pooled(frames).compute()
    _assert_metrics(metrics, sklearn_pixel_metrics(*_pixels(frames)))
    assert metrics.exact and metrics.error_bounds == dict.fromkeys(metrics.error_bounds, 0.0)


def _issue_case(seed):
    """70 % of the negatives spread over distinct float32 scores within 1/128 of 1.0 (one
    1/64 bin of the old histogram), the rest lower; 9 % of the positives inside the block
    too, so the 95 % crossing falls in it."""
    rng = np.random.default_rng(seed)
    negatives = np.r_[
        1.0 + rng.uniform(-1 / 130, 1 / 130, 7000), rng.uniform(0.0, 0.9, 3000)
    ].astype(np.float32)
    positives = np.r_[rng.uniform(1.02, 9.0, 910), 1.0 + rng.uniform(-1 / 130, 1 / 130, 90)]
    scores = np.r_[positives.astype(np.float32), negatives]
    labels = np.r_[np.ones(1000, bool), np.zeros(10000, bool)]
    order = rng.permutation(scores.size)
    # Ten frames of 1100 pixels each.
    return [
        (scores[order][i::10].reshape(20, 55), np.where(labels[order][i::10], 2, 1).reshape(20, 55))
        for i in range(10)
    ]


def test_fpr95_is_exact_when_most_negatives_are_tied_near_one_value():
    frames = _issue_case(5)
    scores, labels = _pixels(frames)
    metrics = _pooled(frames).compute()
    expected = sklearn_pixel_metrics(scores, labels)
    _assert_metrics(metrics, expected)
    assert metrics.p_fpr95 == pytest.approx(oracle_fpr95(scores, labels), abs=1e-12)
    # The case discriminates: read from 1/64-unit bins, the crossing takes the whole block.
    binned = np.rint(scores.astype(np.float64) * 64) / 64
    assert sklearn_fpr95(labels, binned) - expected["p_fpr95"] > 0.2
    assert 0.2 < expected["p_fpr95"] < 0.6


def test_all_equal_scores_are_one_tie():
    frames = [
        (np.full((6, 7), 3.5, np.float32), np.where(np.eye(6, 7) > 0, 2, 0)) for _ in range(3)
    ]
    metrics = _pooled(frames).compute()
    _assert_metrics(metrics, sklearn_pixel_metrics(*_pixels(frames)))
    assert (metrics.p_auroc, metrics.p_fpr95) == (0.5, 1.0)
    assert metrics.p_ap == pytest.approx(6 / 42)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_uint8_maps_equal_sklearn(seed):
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(4):
        mask = np.where(rng.random((9, 11)) < 0.3, 2, 0).astype(np.uint8)
        score = np.clip(rng.normal(100, 40, (9, 11)) + 30 * (mask == 2), 0, 255).astype(np.uint8)
        frames.append((score, mask))
    frames[0][1][0, :2] = (2, 0)
    metrics = _pooled(frames).compute()
    _assert_metrics(metrics, sklearn_pixel_metrics(*_pixels(frames)))
    assert metrics.exact


def test_float64_scores_keep_differences_below_float32_precision():
    # 1 + 1e-12 and 1 are one float32 but two float64 scores; the metrics keep them apart.
    score = np.array([[1.0 + 1e-12, 1.0, 1.0, 0.5]])
    mask = np.array([[2, 0, 2, 0]])
    metrics = _pooled([(score, mask)]).compute()
    _assert_metrics(metrics, sklearn_pixel_metrics(score.ravel(), mask.ravel() == 2))
    assert metrics.p_auroc == pytest.approx(0.875)
    # A float32 frame pooled with it is widened, exactly.
    more = (np.array([[0.25, 1.0]], np.float32), np.array([[2, 0]]))
    metrics = _pooled([(score, mask), more]).compute()
    _assert_metrics(metrics, sklearn_pixel_metrics(*_pixels([(score, mask), more])))


def test_negative_zero_ties_with_zero():
    score = np.array([[-0.0, 0.0, 0.0, -0.0, 1.0]], np.float32)
    mask = np.array([[2, 0, 0, 2, 2]])
    metrics = _pooled([(score, mask)]).compute()
    _assert_metrics(metrics, sklearn_pixel_metrics(score.ravel(), mask.ravel() == 2))
    assert metrics.p_auroc == pytest.approx((1.0 + 2 * 0.5) / 3)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rows=st.sampled_from([1, 2, 3, 5, 8, 40]))
def test_streaming_many_chunks_equals_one_shot(seed, rows):
    # The same 1200 pixels as one frame, or streamed as 1200 / (30 * rows) chunks.
    frames = _float_frames(seed, 40, (1, 30), ties=bool(seed % 2))
    scores = np.concatenate([s for s, _ in frames])
    masks = np.concatenate([m for _, m in frames])
    chunks = [(scores[i : i + rows], masks[i : i + rows]) for i in range(0, 40, rows)]
    streamed, whole = _pooled(chunks), _pooled([(scores, masks)])
    ours, theirs = streamed.pixels.table(), whole.pixels.table()
    assert ours.exact and theirs.exact and ours.pixels == theirs.pixels == 1200
    for name in ("low", "positives", "negatives"):
        assert np.array_equal(getattr(ours, name), getattr(theirs, name)), name
    pixel_keys = ("p_auroc", "p_ap", "p_aupr", "p_fpr95", "p_fpr95_interp")
    assert [getattr(streamed.compute(), k) for k in pixel_keys] == [
        getattr(whole.compute(), k) for k in pixel_keys
    ]


def test_per_pixel_oracle_agrees_on_random_frames():
    for seed in range(8):
        frames = _float_frames(seed, 3, (8, 9), ties=seed % 2 == 1)
        scores, labels = _pixels(frames)
        assert _pooled(frames).compute().p_fpr95 == pytest.approx(
            oracle_fpr95(scores, labels), abs=1e-12
        )


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    max_entries=st.sampled_from([4, 8, 32, 128]),
    ties=st.booleans(),
)
def test_coarsened_counts_bound_every_metrics_error(seed, max_entries, ties):
    frames = _float_frames(seed, 5, (11, 13), ties)
    accumulator = _pooled(frames, max_entries=max_entries)
    metrics = accumulator.compute()
    assert accumulator.pixels.table().size <= max_entries
    expected = sklearn_pixel_metrics(*_pixels(frames))
    for key, value in expected.items():
        assert abs(getattr(metrics, key) - value) <= metrics.error_bounds[key] + 1e-12, key


def test_pools_coarsened_apart_merge_without_their_ranges_running_together():
    # How evaluate pools a split: one pool per anomaly type, each coarsened on its own, then
    # merged. Two pools of continuous scores whose ranges interleave must not chain into a
    # few huge ranges: the merge keeps about as many entries as the pools, no entry holds
    # more than a small share of the pixels, and the bounds stay about those of one pool
    # fed every frame.
    rng = np.random.default_rng(7)
    pools, frames = [PooledScoreCounts(max_entries=2048) for _ in range(2)], []
    single = PooledScoreCounts(max_entries=2048)
    for index in range(40):
        mask = np.where(rng.random((48, 64)) < 0.05, 2, 0)
        score = (rng.gamma(2.0, 20.0, mask.shape) + 60.0 * (mask == 2)).astype(np.float32)
        pools[index % 2].update(score, mask)
        single.update(score, mask)
        frames.append((score, mask))
    assert not pools[0].table().exact and not pools[1].table().exact
    merged = PooledScoreCounts(max_entries=2048)
    for pool in pools:
        merged.add_pool(pool)
    table = merged.table()
    weight = table.positives.astype(np.int64) + table.negatives
    assert table.size >= min(p.table().size for p in pools) // 2
    assert weight.max() <= 0.01 * table.pixels
    values, bounds = pixel_metrics(table)
    single_bounds = pixel_metrics(single.table())[1]
    expected = sklearn_pixel_metrics(*_pixels(frames))
    for key, value in expected.items():
        assert abs(values[key] - value) <= bounds[key] + 1e-12, key
        assert bounds[key] <= 1.5 * single_bounds[key] + 1e-9, key


def test_a_heavy_tie_keeps_its_exact_entry_when_the_table_is_coarsened():
    # The issue's case with the block exactly tied at 1.0 and many sparse scores around:
    # the coarsened table still gives P.FPR95 exactly, with no bound.
    rng = np.random.default_rng(2)
    frames = []
    for _ in range(8):
        mask = np.where(rng.random((30, 40)) < 0.1, 2, 0)
        score = np.where(rng.random((30, 40)) < 0.7, 1.0, rng.uniform(0, 0.99, (30, 40)))
        score = np.where(mask == 2, rng.uniform(1.001, 5, (30, 40)), score).astype(np.float32)
        score[mask == 2] = np.where(
            rng.random(np.count_nonzero(mask == 2)) < 0.1, 1.0, score[mask == 2]
        )
        frames.append((score, mask))
    accumulator = _pooled(frames, max_entries=256)
    metrics = accumulator.compute()
    assert not accumulator.pixels.table().exact  # coarsened: 5 k distinct scores
    assert metrics.error_bounds["p_fpr95"] == 0.0
    expected = sklearn_pixel_metrics(*_pixels(frames))
    assert metrics.p_fpr95 == pytest.approx(expected["p_fpr95"], abs=1e-12)
    assert expected["p_fpr95"] > 0.5


def test_pool_memory_stays_bounded_over_many_frames():
    # 100 frames of 4096 distinct scores each (410 k in all) into a pool of 2048 entries:
    # the pool never holds more than 2048 entries of 16 bytes, and the peak of an update
    # (its working copies and the frame's own table included) stays within a fixed
    # multiple of the pooled table and one frame's table together.
    import tracemalloc

    max_entries, shape = 2048, (64, 64)
    held_limit = 16 * max_entries
    working_limit = 8 * (held_limit + 16 * shape[0] * shape[1])
    rng = np.random.default_rng(0)
    accumulator = MetricsAccumulator(max_entries=max_entries)
    tracemalloc.start()
    peak = 0
    try:
        for _ in range(100):
            score = rng.random(shape, dtype=np.float32) * 255
            mask = np.where(rng.random(shape) < 0.05, 2, 0)
            held = accumulator.pixels.nbytes
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            accumulator.update(score, 0.0, mask)
            peak = max(peak, held + tracemalloc.get_traced_memory()[1] - before)
            assert accumulator.pixels.nbytes <= held_limit
    finally:
        tracemalloc.stop()
    print(f"pool of {max_entries} entries, 100 frames: peak {peak} bytes ({working_limit} allowed)")
    assert peak <= working_limit
    assert accumulator.pixels.table().size <= max_entries
    assert not accumulator.compute().exact


def test_counts_past_uint32_widen_instead_of_wrapping():
    keys = score_keys(np.array([1.0, 2.0], np.float32))
    big = np.array([2**32 - 10, 5], np.uint32)
    tables = [ScoreCounts(keys, keys, big, big, 2 * int(big.sum())) for _ in range(2)]
    merged = merge(tables)
    assert merged.positives.dtype == np.int64
    assert merged.positives.tolist() == [2 * (2**32 - 10), 10]
    # The same through insertion into a larger table.
    many = score_keys(np.arange(1.0, 9.0, dtype=np.float32))
    fives = np.full(8, 5, np.uint32)
    larger = ScoreCounts(many, many, fives, fives, 80)
    full = np.array([2**32 - 1], np.uint32)
    one = ScoreCounts(many[:1], many[:1], full, full, 2 * (2**32 - 1))
    merged = merge([larger, one])
    assert merged.negatives.dtype == np.int64
    assert merged.negatives.tolist() == [2**32 + 4, 5, 5, 5, 5, 5, 5, 5]


def test_curve_thresholds_are_the_scores():
    score = np.array([[3.0, 2.0, 2.0, 1.0, 0.5, 0.25]], np.float32)
    mask = np.array([[2, 0, 2, 0, 0, 2]])
    curve = _pooled([(score, mask)]).curve()
    # Runs of negatives between positives count as one point (at their lowest score).
    assert curve.thresholds.tolist() == [np.inf, 3.0, 2.0, 0.5, 0.25]
    # Its points are scikit-learn's, less those inside a run of negatives.
    fpr, tpr, _ = roc_curve(mask.ravel() == 2, score.ravel(), drop_intermediate=False)
    theirs = {(round(f, 12), round(t, 12)) for f, t in zip(fpr, tpr, strict=True)}
    ours = {(round(f, 12), round(t, 12)) for f, t in zip(curve.fpr, curve.tpr, strict=True)}
    assert ours <= theirs and len(theirs - ours) == 1
