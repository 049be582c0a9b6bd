"""``detection_coverage``: how much of each showing object the detection mask covers, per
placement, against hand counts and a per-pixel loop over random masks."""

from __future__ import annotations

import numpy as np
import pytest

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.evaluation.objects import (
    ObjectEvaluationError,
    ObjectFrame,
    ObjectRun,
    detection_coverage,
)
from allo_mrad_ros.sequence import GroundTruthObject

WIDTH, HEIGHT = 8, 6
CAMERA = CameraIntrinsics(width=WIDTH, height=HEIGHT, fx=10.0, fy=10.0, cx=4.0, cy=3.0)


def truth(object_id: int, placement: str) -> GroundTruthObject:
    return GroundTruthObject(
        id=object_id,
        type="box",
        stamp_ns=0,
        position=np.zeros(3),
        velocity=np.zeros(3),
        quaternion=np.array([0.0, 0.0, 0.0, 1.0]),
        size=np.full(3, 0.3),
        extra={"placement": placement},
    )


def frame(index: int, mask: np.ndarray, showing: set[int]) -> ObjectFrame:
    return ObjectFrame(
        index=index,
        split="val",
        stamp_ns=index,
        pose=np.eye(4),
        regions=(),
        depth=np.zeros((HEIGHT, WIDTH), np.float32),
        mask_pixels=np.flatnonzero(mask).astype(np.int32),
        frame_flagged=bool(mask.any()),
        showing=frozenset(showing),
        detect_ms=0.0,
        trajectory="val/0",
    )


def test_counts_touched_and_half_covered_object_frames_per_placement():
    labels = np.zeros((HEIGHT, WIDTH), np.uint16)
    labels[0, 0:4] = 1  # front, 4 pixels
    labels[3:5, 5:7] = 2  # space, 4 pixels
    first = np.zeros((HEIGHT, WIDTH), bool)
    first[0, 0:2] = True  # 2 of the front object's 4: touched and half covered
    first[2, 2] = True  # detection elsewhere: the space object is missed
    second = np.zeros((HEIGHT, WIDTH), bool)
    second[0, 3] = True  # 1 of 4: touched, not half
    second[3:5, 5:7] = True  # all of the space object
    run = ObjectRun("t", CAMERA, (truth(1, "front"), truth(2, "space")), [])
    run.frames = [frame(10, first, {1, 2}), frame(11, second, {1, 2}), frame(12, first, set())]
    masks = {10: labels, 11: labels, 12: np.zeros_like(labels)}

    coverage = detection_coverage(run, masks.get)

    assert coverage == {
        "front": {"object_frames": 2, "touched": 2, "half_covered": 1},
        "space": {"object_frames": 2, "touched": 1, "half_covered": 1},
        "all": {"object_frames": 4, "touched": 3, "half_covered": 2},
    }


def test_agrees_with_a_per_pixel_loop_on_random_masks():
    rng = np.random.default_rng(3)
    objects = (truth(1, "front"), truth(2, "behind"), truth(5, "space"))
    placement = {o.id: o.extra["placement"] for o in objects}
    run = ObjectRun("t", CAMERA, objects, [])
    masks = {}
    for index in range(40):
        labels = rng.choice([0, 1, 2, 5], size=(HEIGHT, WIDTH), p=[0.7, 0.1, 0.1, 0.1])
        labels = labels.astype(np.uint16)
        detected = rng.random((HEIGHT, WIDTH)) < rng.uniform(0.0, 0.8)
        masks[index] = labels
        run.frames.append(frame(index, detected, {int(v) for v in np.unique(labels) if v}))

    expected: dict[str, dict[str, int]] = {}
    for f in run.frames:
        detected = np.zeros(HEIGHT * WIDTH, bool)
        detected[f.mask_pixels] = True
        for object_id in f.showing:
            total = covered = 0
            for y in range(HEIGHT):
                for x in range(WIDTH):
                    if masks[f.index][y, x] == object_id:
                        total += 1
                        covered += bool(detected[y * WIDTH + x])
            for group in (placement[object_id], "all"):
                row = expected.setdefault(
                    group, {"object_frames": 0, "touched": 0, "half_covered": 0}
                )
                row["object_frames"] += 1
                row["touched"] += covered > 0
                row["half_covered"] += covered >= total / 2

    assert detection_coverage(run, masks.get) == expected


def test_an_instance_mask_of_another_size_is_refused_naming_the_frame():
    run = ObjectRun("t", CAMERA, (truth(1, "front"),), [])
    run.frames = [frame(7, np.zeros((HEIGHT, WIDTH), bool), {1})]
    with pytest.raises(ObjectEvaluationError, match="frame index 7"):
        detection_coverage(run, lambda index: np.ones((HEIGHT, WIDTH + 1), np.uint16))
