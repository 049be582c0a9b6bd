"""The detector's regions against a float64 per-pixel oracle (scipy's labelling, loops)."""

from __future__ import annotations

import itertools
import json
import math

import cv2
import numpy as np
import pytest
from scipy import ndimage

from allo_mrad_ros.detector import MradParams, Region, detect
from allo_mrad_ros.detector.regions import (
    PEAK_TABLE,
    RegionTableError,
    extract_regions,
    normal_peaks,
    region_score,
)
from allo_mrad_ros.example_scene import example_pair

STRUCTURE = {4: ndimage.generate_binary_structure(2, 1), 8: np.ones((3, 3), bool)}


def empirical_fraction(peak: float, table: list[float]) -> float:
    """The share of ``table`` below ``peak``, ties counting half, by a loop over the table."""
    below = sum(1 for value in table if value < peak)
    equal = sum(1 for value in table if value == peak)
    return (below + 0.5 * equal) / len(table)


def shipped_table() -> dict:
    return json.loads(PEAK_TABLE.read_text(encoding="utf-8"))


def oracle_regions(
    work_mask: np.ndarray, evidence: np.ndarray, mask: np.ndarray, connectivity: int
) -> list[dict]:
    """Each region's statistics by loops over its pixels, in the raster order of the first.

    The image-resolution figures come from labelling the enlarged ``mask`` itself; the
    evidence figures from the processing-resolution ``work_mask``.
    """
    described = []
    for labelled, values in ((work_mask, evidence), (mask, None)):
        labels, count = ndimage.label(labelled != 0, structure=STRUCTURE[connectivity])
        pixels: dict[int, list[tuple[int, int]]] = {}
        for row in range(labels.shape[0]):
            for column in range(labels.shape[1]):
                if labels[row, column]:
                    pixels.setdefault(int(labels[row, column]), []).append((row, column))
        assert len(pixels) == count
        regions = []
        for members in sorted(pixels.values(), key=lambda p: p[0]):  # raster order of first
            rows = [r for r, _ in members]
            columns = [c for _, c in members]
            box = (min(columns), min(rows), max(columns) - min(columns) + 1)
            box += (max(rows) - min(rows) + 1,)
            region = {"box": box, "area": len(members)}
            region["centroid"] = (
                sum(float(c) for c in columns) / len(members),
                sum(float(r) for r in rows) / len(members),
            )
            if values is not None:
                scores = [float(values[r, c]) for r, c in members]
                region["peak"] = max(scores)
                region["mean"] = sum(scores) / len(scores)
            regions.append(region)
        described.append(regions)
    work, image = described
    assert len(work) == len(image)
    return [
        {
            "box": big["box"],
            "area": big["area"],
            "centroid": big["centroid"],
            "work_box": small["box"],
            "work_area": small["area"],
            "peak_score": small["peak"],
            "mean_score": small["mean"],
        }
        for small, big in zip(work, image, strict=True)
    ]


def assert_match(regions: tuple[Region, ...], expected: list[dict]) -> None:
    assert len(regions) == len(expected)
    for region, want in zip(regions, expected, strict=True):
        assert region.box == want["box"]
        assert region.area == want["area"]
        assert region.work_box == want["work_box"]
        assert region.work_area == want["work_area"]
        np.testing.assert_allclose(region.centroid, want["centroid"], rtol=0, atol=1e-9)
        assert region.peak_score == want["peak_score"]
        assert region.mean_score == pytest.approx(want["mean_score"], rel=1e-12, abs=1e-9)
        table = shipped_table()["peaks"]
        assert region.score == pytest.approx(empirical_fraction(want["peak_score"], table))
        assert 0.0 <= region.score <= 1.0


def random_mask(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    for _ in range(rng.integers(0, 7)):
        y, x = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        mask[y : y + rng.integers(1, 8), x : x + rng.integers(1, 10)] = 255
    # Isolated pixels, some touching others only at a corner.
    mask[rng.random(shape) > 0.93] = 255
    return mask


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize(
    "image_shape",
    [(27, 41), (54, 82), (81, 164), (40, 47), (100, 131)],
    ids=["same", "x2", "x3-x4", "odd", "non-integer"],
)
@pytest.mark.parametrize("seed", range(3))
def test_regions_match_the_oracle(connectivity, image_shape, seed):
    rng = np.random.default_rng(seed)
    work_mask = random_mask(rng, (27, 41))
    evidence = (rng.random((27, 41)) * 255).astype(np.float32)
    # The detector's enlargement of its mask (detector.images.nearest_upscale).
    mask = cv2.resize(work_mask, image_shape[::-1], interpolation=cv2.INTER_NEAREST)
    regions = extract_regions(work_mask, evidence, image_shape, connectivity)
    assert_match(regions, oracle_regions(work_mask, evidence, mask, connectivity))


def test_an_empty_mask_has_no_region_and_bad_arguments_are_named():
    empty = np.zeros((5, 6), np.uint8)
    assert extract_regions(empty, np.ones((5, 6), np.float32), (10, 12), 8) == ()
    with pytest.raises(ValueError, match="connectivity"):
        extract_regions(empty, np.zeros((5, 6), np.float32), (5, 6), 6)
    with pytest.raises(ValueError, match="smaller"):
        extract_regions(empty, np.zeros((5, 6), np.float32), (4, 6), 8)
    with pytest.raises(ValueError, match="evidence"):
        extract_regions(empty, np.zeros((6, 5), np.float32), (5, 6), 8)


@pytest.fixture(scope="module")
def pair():
    return example_pair(270, 480, seed=3)


def blurred_params(**changes) -> MradParams:
    # pixel_score "blurred": the result's map is the evidence the regions were grown on.
    return MradParams(pixel_score="blurred", image_score="area", **changes)


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("process_scale", [0.25, 0.3, 1.0])
def test_the_detectors_regions_are_its_masks_regions(pair, connectivity, process_scale):
    # Two copies of the object so that there is more than one region.
    query = pair.query.copy()
    rows, columns = np.nonzero(pair.object_mask)
    query[rows + 60, columns - 150] = pair.query[rows, columns]
    params = blurred_params(connectivity=connectivity, process_scale=process_scale)
    result = detect(query, pair.reference, params)
    assert result.regions, "the example's objects were not found"
    assert len(result.regions) >= 2
    expected = oracle_regions(result.work_mask, result.work_score, result.mask, connectivity)
    assert_match(result.regions, expected)
    assert sum(region.area for region in result.regions) == result.area
    # The regions do not depend on which map the result ranks pixels with.
    for pixel_score in ("continuous", "regions"):
        other = detect(query, pair.reference, params.replace(pixel_score=pixel_score))
        assert other.regions == result.regions


@pytest.mark.parametrize("method", ["PAD", "RXD"])
def test_the_baselines_regions_are_their_masks_regions(pair, method):
    from allo_mrad_ros.detector import METHODS

    params = MradParams(connectivity=4, score_scaling="per_image")
    result = METHODS[method](pair.query, pair.reference, params)
    assert result.regions
    expected = oracle_regions(result.work_mask, result.work_score, result.mask, 4)
    assert_match(result.regions, expected)


def test_the_region_score_is_a_monotone_map_of_the_peak_onto_zero_to_one():
    table = normal_peaks()
    peaks = np.concatenate(
        [[-5.0, 0.0], np.linspace(0.0, 255.0, 1021), table, np.nextafter(table, 0.0), [300.0]]
    )
    peaks.sort()
    scores = [region_score(peak) for peak in peaks]
    assert all(0.0 <= score <= 1.0 for score in scores)
    assert all(a <= b for a, b in itertools.pairwise(scores))
    # Below every normal region's peak 0, above all of them 1, and the scale is used.
    assert region_score(table[0] - 1.0) == 0.0 and region_score(table[-1] + 1.0) == 1.0
    assert len(set(scores)) > len(np.unique(table))
    # On detected regions too: ordered by peak, ordered by score.
    rng = np.random.default_rng(7)
    work_mask = random_mask(rng, (40, 60))
    evidence = (rng.random((40, 60)) * 255).astype(np.float32)
    regions = sorted(extract_regions(work_mask, evidence, (40, 60), 8), key=lambda r: r.peak_score)
    assert len(regions) > 3
    assert all(a.score <= b.score for a, b in itertools.pairwise(regions))


@pytest.mark.parametrize("source", ["shipped", "ties"])
def test_the_region_score_is_the_empirical_fraction_of_normal_peaks_below(source):
    if source == "shipped":
        table = [float(v) for v in shipped_table()["peaks"]]
        score = region_score
    else:  # repeated values: each tie counts half
        table = [10.0, 20.0, 20.0, 20.0, 30.0, 40.0, 40.0]
        score = lambda peak: region_score(peak, np.asarray(table))  # noqa: E731
    for peak in table:
        assert score(peak) == pytest.approx(empirical_fraction(peak, table), abs=1e-12)
    # Between and beyond the samples too.
    for low, high in itertools.pairwise(sorted(set(table))):
        middle = (low + high) / 2.0
        assert score(middle) == pytest.approx(empirical_fraction(middle, table), abs=1e-12)


def test_the_shipped_table_is_sorted_finite_and_says_how_it_was_made():
    table = shipped_table()
    peaks = table["peaks"]
    assert len(peaks) == table["count"] >= 50
    assert all(math.isfinite(value) and 0.0 <= value <= 255.0 for value in peaks)
    assert peaks == sorted(peaks)
    assert table["command"].startswith("python -m benchmarks.region_calibration")
    assert table["sequence_command"].startswith("allo-synth generate --preset bench-val")
    assert "normal" in table["description"]
    np.testing.assert_array_equal(normal_peaks(), np.asarray(peaks))


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("not json", "cannot read"),
        ('{"rows": []}', "cannot read"),
        ('{"peaks": []}', "non-empty"),
        ('{"peaks": [2.0, 1.0]}', "sorted"),
        ('{"peaks": [1.0, NaN]}', "finite"),
    ],
)
def test_a_malformed_table_is_named(tmp_path, text, problem):
    path = tmp_path / "peaks.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(RegionTableError, match=problem) as caught:
        normal_peaks(path)
    assert str(path) in str(caught.value)
    with pytest.raises(RegionTableError, match="cannot read"):
        normal_peaks(tmp_path / "absent.json")
