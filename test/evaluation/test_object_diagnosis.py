"""``diagnose_objects``: where each ground-truth object was lost, on a scene built by hand
(regions where points project from a sweeping camera, instance masks drawn around them):
one object matched, one without a region, one whose regions score low, one seen too briefly
to confirm, one confirmed away from its true position, one so far that parallax never places
it; and its recall against the metrics'."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from allo_mrad_ros.evaluation.objects import (
    ObjectFrame,
    ObjectRun,
    diagnose_objects,
    score_run,
)
from allo_mrad_ros.sequence import GroundTruthObject

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "objects"))
from objects_scene import CAMERA, SPACE, project, region_at, scene_params, sweep

FPS = 10.0
FRAMES = 40
EXTENT = 8
# Points 9-11 m ahead of the sweep, far enough apart in the image not to be confused.
SEEN = np.array([0.5, 0.0, 0.3])  # regions every frame: matched
UNSEEN = np.array([-0.8, 0.5, -0.6])  # in the instance mask, never under the detection mask
FAINT = np.array([-1.5, 1.0, 0.6])  # regions scoring 0.1, below min_region_score
BRIEF = np.array([1.2, -0.5, -0.8])  # regions in two frames only
ELSEWHERE = np.array([-0.2, 1.0, 1.0])  # regions here, its table position 2 m away
OFFSET = np.array([0.0, 2.0, 0.0])
# 100 km out, as the Moon is to the arm: its rays keep their direction along the sweep.
FAR = np.array([-2.0, -10.0, 0.0]) + 1e5 * np.array([-0.3, 1.0, 0.2]) / np.sqrt(1.13)


def truth(object_id: int, position: np.ndarray) -> GroundTruthObject:
    return GroundTruthObject(
        id=object_id,
        type=f"thing{object_id}",
        stamp_ns=0,
        position=position,
        velocity=np.zeros(3),
        quaternion=np.array([0.0, 0.0, 0.0, 1.0]),
        size=np.full(3, 0.2),
        extra={"placement": "space"},
    )


def build() -> tuple[ObjectRun, list[np.ndarray]]:
    shown = {1: SEEN, 2: UNSEEN, 3: FAINT, 4: BRIEF, 5: ELSEWHERE, 6: FAR}
    frames, labels_of = [], []
    for k in range(FRAMES):
        t = k / FPS
        pose = sweep(t)
        labels = np.zeros((CAMERA.height, CAMERA.width), np.uint16)
        mask = np.zeros_like(labels, dtype=bool)
        regions = []
        for object_id, point in shown.items():
            if object_id == 4 and k >= 2:
                continue
            u, v, _ = project(point, pose)
            region = region_at(u, v, EXTENT, score=0.1 if object_id == 3 else 0.9)
            x, y, w, h = region.box
            labels[y : y + h, x : x + w] = object_id
            if object_id != 2:
                mask[y : y + h, x : x + w] = True
                regions.append(region)
        frames.append(
            ObjectFrame(
                index=k,
                split="val",
                stamp_ns=round(t * 1e9),
                pose=pose,
                regions=tuple(regions),
                depth=SPACE,
                mask_pixels=np.flatnonzero(mask).astype(np.int32),
                frame_flagged=True,
                showing=frozenset(int(v) for v in np.unique(labels) if v),
                detect_ms=0.0,
                trajectory="val/0",
            )
        )
        labels_of.append(labels)
    objects = tuple(truth(i, p + (OFFSET if i == 5 else 0.0)) for i, p in shown.items())
    return ObjectRun("hand", CAMERA, objects, frames), labels_of


def test_each_object_is_followed_to_where_it_was_lost():
    run, labels = build()
    params = scene_params(confirm_hits=3, confirm_window=5, min_region_score=0.5)
    rows = {r.id: r for r in diagnose_objects(run, params, lambda i: labels[i])}
    assert {i: r.cause for i, r in rows.items()} == {
        1: "matched",
        2: "no region",
        3: "regions score low",
        4: "not confirmed",
        5: "beyond match distance",
        6: "not confirmed",
    }
    seen = rows[1]
    assert (seen.frames_showing, seen.frames_touched, seen.frames_tracked) == (40, 40, 40)
    assert (seen.regions, seen.tracks, seen.main_track_regions) == (40, 1, 40)
    assert seen.confirmed_tracks == 1 and seen.matched and seen.eligible
    # Noise-free rays agree at once: it waits from its third hit only for the parallax that
    # places it; the far thing waits every frame from its third, its range unresolved in each.
    assert 0 < seen.main_track_waiting == seen.main_track_unresolved < FRAMES - 2
    far = rows[6]
    assert (far.regions, far.tracks, far.confirmed_tracks) == (40, 1, 0)
    assert far.main_track_waiting == FRAMES - 2 and far.main_track_unresolved == FRAMES - 2
    # Noise-free rays; the match distance 5 % of the range from the last frame's camera.
    last_range = np.linalg.norm(SEEN - sweep((FRAMES - 1) / FPS)[:3, 3])
    assert seen.distance_m < 1e-6 and abs(seen.tolerance_m - 0.05 * last_range) < 1e-9
    assert (rows[2].frames_showing, rows[2].frames_touched) == (40, 0)
    assert (rows[3].frames_touched, rows[3].frames_tracked, rows[3].regions) == (40, 0, 0)
    assert (rows[4].frames_showing, rows[4].regions, rows[4].eligible) == (2, 2, False)
    elsewhere = rows[5]
    assert elsewhere.confirmed_tracks == 1 and not elsewhere.matched
    assert abs(elsewhere.distance_m - 2.0) < 1e-6 and elsewhere.distance_m > elsewhere.tolerance_m


def test_its_recall_is_the_metrics_recall():
    run, labels = build()
    for params in (scene_params(), scene_params(min_region_score=0.0)):
        rows = diagnose_objects(run, params, lambda i: labels[i])
        metrics, _ = score_run(run, params)
        recalled = sum(r.matched and r.eligible for r in rows)
        assert recalled == metrics.overall.recalled
        assert sum(r.eligible for r in rows) == metrics.overall.eligible
