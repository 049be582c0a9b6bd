"""The tracker's per-frame range evidence (:func:`observe`, one range image per frame for all
regions) against :func:`region_rays` region by region, with and without the detection mask."""

from __future__ import annotations

import numpy as np
import pytest
from objects_scene import CAMERA, DEPTH_SHAPE, region_at

from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.objects import region_rays
from allo_mrad_ros.objects.rays import observe

POSE = look_at([0.0, -10.0, 0.0], [0.0, 0.0, 0.0])


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("with_mask", [False, True])
def test_observe_gives_each_region_the_interval_region_rays_gives_it(seed, with_mask):
    rng = np.random.default_rng(seed)
    depth = rng.uniform(2.0, 30.0, DEPTH_SHAPE).astype(np.float32)
    depth[rng.random(DEPTH_SHAPE) < 0.4] = 0.0  # space here and there
    regions = [
        region_at(
            float(rng.uniform(-10, CAMERA.width + 10)),
            float(rng.uniform(-10, CAMERA.height + 10)),
            extent=int(rng.integers(1, 90)),
            score=float(rng.uniform(0, 1)),
        )
        for _ in range(25)
    ]
    mask = None
    if with_mask:
        mask = np.where(rng.random((CAMERA.height, CAMERA.width)) < 0.05, 255, 0).astype(np.uint8)
    options = {"min_range": 0.5, "max_range": 40.0, "surface_quantile": 0.2}
    seen = observe(regions, POSE, CAMERA, depth, mask=mask, min_score=0.3, **options)
    kept = [i for i, r in enumerate(regions) if r.score >= 0.3]
    assert seen.indices.tolist() == kept
    for j, index in enumerate(kept):
        one = region_rays(regions[index], POSE, CAMERA, depth, mask=mask, **options)
        assert seen.high[j] == one.max_range and seen.low[j] == one.min_range
        assert bool(seen.over_surface[j]) == one.over_surface
        np.testing.assert_allclose(seen.directions[j], one.centre, atol=1e-12)


def test_the_tracker_takes_nan_inf_and_negative_depth_as_space_as_a_cleaned_depth():
    from objects_scene import sweep

    from allo_mrad_ros.objects import ObjectParams, ObjectTracker
    from allo_mrad_ros.objects.rays import checked_depth

    rng = np.random.default_rng(3)
    dirty = rng.uniform(2.0, 12.0, DEPTH_SHAPE).astype(np.float32)
    marks = rng.random(DEPTH_SHAPE)
    dirty[marks < 0.2] = np.nan
    dirty[(marks >= 0.2) & (marks < 0.4)] = np.inf
    dirty[(marks >= 0.4) & (marks < 0.5)] = -3.0
    dirty[(marks >= 0.5) & (marks < 0.6)] = 0.0
    clean = checked_depth(dirty)
    assert np.isfinite(clean).all() and (clean >= 0).all()
    points = rng.uniform([-3, -2, -2], [3, 2, 2], (6, 3))
    trackers = [ObjectTracker(ObjectParams(), CAMERA) for _ in range(2)]
    for k in range(30):
        t = k / 10.0
        pose = sweep(t, speed=1.0)
        local = (points - pose[:3, 3]) @ pose[:3, :3]
        uv = local[:, :2] / local[:, 2:] * 500.0 + [319.5, 239.5]
        regions = [region_at(float(u), float(v), extent=20) for u, v in uv]
        got = [
            tracker.update(regions, pose, depth, t)
            for tracker, depth in zip(trackers, (dirty, clean), strict=True)
        ]
        assert len(got[0]) == len(got[1])
        for a, b in zip(*got, strict=True):
            assert (a.id, a.state, a.in_view, a.region) == (b.id, b.state, b.in_view, b.region)
            np.testing.assert_array_equal(a.position, b.position)
