"""The tracker's per-object bookkeeping on a busy scene, against a plain per-object loop:
each object's hits and score follow from the regions matched with it and the frames it was
in view, as the module text states them; the records ``update`` returns are the ones its
``objects`` property builds; the pose check accepts and refuses what ``validate_transform``
does."""

from __future__ import annotations

import numpy as np
import pytest
from objects_scene import CAMERA, DEPTH_SHAPE, project, region_at, scene_params, sweep

from allo_mrad_ros.geometry import PoseError, look_at, validate_transform
from allo_mrad_ros.objects import ObjectsError, ObjectTracker
from allo_mrad_ros.objects.rays import checked_pose

FPS = 10.0


def busy_scene(seed: int, frames: int = 60):
    """Frames of a sweep past 30 points: each frame a rotating dozen of the points in the
    image are seen (scores drawn per region, some below the start floor), the rest missed
    or out of view; a wall stands 6 m away behind the right half of the image (points
    beyond it are hidden). Yields (regions, pose, depth, stamp)."""
    rng = np.random.default_rng(seed)
    points = np.c_[rng.uniform(-4, 4, 30), rng.uniform(-3, 10, 30), rng.uniform(-2, 2, 30)]
    depth = np.zeros(DEPTH_SHAPE, np.float32)
    depth[:, DEPTH_SHAPE[1] // 2 :] = 6.0
    for k in range(frames):
        t = k / FPS
        pose = sweep(t, speed=0.4)
        regions = []
        for i in (np.arange(12) + 5 * k) % len(points) if k >= 2 else range(len(points)):
            u, v, z = project(points[i], pose)
            if z > 0.5 and 0 <= u < CAMERA.width and 0 <= v < CAMERA.height:
                score = float(rng.choice([0.3, 0.6, 0.9, 1.0]))
                regions.append(region_at(u, v, 10, score=score))
        yield regions, pose, depth, t


def test_hits_and_scores_follow_the_matched_regions_and_in_view_frames():
    """The window rule as a plain loop: an object's frame counts when a region was matched
    with it (a hit, that region's score) or when it was in view and none was (a miss,
    score 0); its score is the sum of its last confirm_window counted frames over
    confirm_window, at most 1; its hits are the regions matched with it."""
    params = scene_params(
        min_region_score=0.5, hit_region_score=0.25, end_misses=4, reacquire_s=0.0
    )
    window = params.confirm_window
    tracker = ObjectTracker(params, CAMERA)
    counted: dict[int, list[float]] = {}
    hits: dict[int, int] = {}
    checked = misses = 0
    for regions, pose, depth, t in busy_scene(3):
        for record in tracker.update(regions, pose, depth, t):
            frames = counted.setdefault(record.id, [])
            if record.region is not None:
                frames.append(regions[record.region].score)
                hits[record.id] = hits.get(record.id, 0) + 1
            elif record.in_view:
                frames.append(0.0)
                misses += 1
            expected = min(1.0, max(sum(frames[-window:]), 0.0) / window)
            assert record.score == pytest.approx(expected, rel=1e-12, abs=1e-15), record.id
            assert record.hits == hits[record.id]
            checked += 1
    # The scene exercises the rule: many objects, misses among the hits, windows that roll.
    assert len(counted) >= 20 and misses >= 50 and checked >= 500
    assert max(len(frames) for frames in counted.values()) > window


def test_the_records_of_a_frame_are_those_of_the_objects_property():
    params = scene_params(min_region_score=0.5, hit_region_score=0.25, end_misses=4)
    tracker = ObjectTracker(params, CAMERA)
    compared = 0
    for regions, pose, depth, t in busy_scene(5, frames=40):
        live = [r for r in tracker.update(regions, pose, depth, t) if r.state != "ended"]
        held = tracker.objects
        assert [r.id for r in live] == [o.id for o in held]
        for record, obj in zip(live, held, strict=True):
            for field in ("state", "size", "score", "range_resolved", "hits", "first_stamp"):
                assert getattr(record, field) == getattr(obj, field), field
            assert record.last_hit_stamp == obj.last_hit_stamp
            assert np.array_equal(record.position, obj.position)
            assert np.array_equal(record.covariance, obj.covariance)
            # The property reports no frame's region and nothing in view.
            assert obj.region is None and not obj.in_view
            compared += 1
    assert compared >= 300


def _poses(seed: int):
    """Camera poses near and across validate_transform's tolerances: rigid ones, rotations
    off orthonormal by 1e-8 to 1e-4, last rows off by 1e-11 to 1e-7, reflections, entries
    not finite, and entries so large that their sum overflows."""
    rng = np.random.default_rng(seed)
    for _ in range(400):
        eye = rng.normal(size=3) * 10
        pose = look_at(eye, eye + rng.normal(size=3))
        kind = rng.integers(6)
        if kind == 1:
            pose[:3, :3] += rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-8, -4)
        elif kind == 2:
            pose[3] += rng.normal(size=4) * 10.0 ** rng.uniform(-11, -7)
        elif kind == 3:
            pose[:3, 0] *= -1.0
        elif kind == 4:
            pose[rng.integers(4), rng.integers(4)] = rng.choice([np.nan, np.inf, -np.inf])
        elif kind == 5:
            pose[:3, 3] = 1e308
        yield pose


@pytest.mark.parametrize("seed", [0, 1])
def test_the_pose_check_accepts_and_refuses_as_validate_transform(seed):
    accepted = refused = 0
    for pose in _poses(seed):
        try:
            expected = validate_transform(pose, "camera pose")
        except PoseError as error:
            with pytest.raises(ObjectsError) as refusal:
                checked_pose(pose)
            assert str(refusal.value) == str(error)
            refused += 1
        else:
            assert np.array_equal(checked_pose(pose), expected)
            accepted += 1
    assert accepted >= 100 and refused >= 100
