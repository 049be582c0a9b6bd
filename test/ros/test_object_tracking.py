"""The node's tracker across frames: started over on a new camera, new parameters or after
untracked frames, its objects then reported ended, ids counting on; a stamp going back ends
every object."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.objects import ObjectParams, ObjectsError
from allo_mrad_ros.ros.object_tracking import ObjectTracking

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "objects"))
from objects_scene import CAMERA, SPACE, project, region_at, sweep

POINT = np.array([0.5, 0.0, 0.2])  # 10 m ahead of the sweep's path
PARAMS = ObjectParams()


def frame(tracking: ObjectTracking, t: float, camera: CameraIntrinsics = CAMERA, **kw):
    pose = sweep(t, speed=2.0)
    u, v, _ = project(POINT, pose, camera)
    return tracking.update(
        camera=camera,
        params=kw.pop("params", PARAMS),
        regions=[region_at(u, v)],
        pose=pose,
        depth=SPACE,
        stamp=t,
        **kw,
    )


def confirm(tracking: ObjectTracking, start: float = 0.0) -> int:
    """Frames until an object is confirmed; its id."""
    for i in range(10):
        update = frame(tracking, start + 0.1 * i)
        confirmed = [o for o in update.objects if o.state == "confirmed"]
        if confirmed:
            assert update.anomalous and update.count("confirmed") == 1
            np.testing.assert_allclose(confirmed[0].position, POINT, atol=0.3)
            return confirmed[0].id
    raise AssertionError("no object confirmed")


@pytest.mark.parametrize(
    "change",
    [
        {"camera": CameraIntrinsics(640, 480, 520.0, 520.0, 319.5, 239.5)},
        {"params": PARAMS.replace(gate_sigma=PARAMS.gate_sigma + 1.0)},
        {"skip": True},
    ],
    ids=["camera", "parameters", "untracked frames"],
)
def test_a_change_starts_over_reporting_the_old_objects_ended_and_ids_count_on(change):
    tracking = ObjectTracking()
    first = confirm(tracking)
    if change.pop("skip", False):
        tracking.skip()
    update = frame(tracking, 1.0, **change)
    ended = [o for o in update.objects if o.state == "ended"]
    assert [o.id for o in ended] == [first]
    fresh = [o for o in update.objects if o.state != "ended"]
    assert len(fresh) == 1 and fresh[0].id > first and fresh[0].state == "tentative"
    assert not update.anomalous


def test_the_same_camera_and_parameters_keep_the_objects():
    tracking = ObjectTracking()
    first = confirm(tracking)
    tracker = tracking.tracker
    update = frame(tracking, 1.0, params=ObjectParams())  # equal, not the same instance
    assert tracking.tracker is tracker
    assert [(o.id, o.state) for o in update.objects] == [(first, "confirmed")]


def test_a_stamp_going_back_ends_every_object():
    tracking = ObjectTracking()
    first = confirm(tracking, start=1.0)
    update = frame(tracking, 0.5)
    assert (first, "ended") in [(o.id, o.state) for o in update.objects]
    assert not update.anomalous


def test_a_refused_input_changes_nothing():
    tracking = ObjectTracking()
    first = confirm(tracking)
    with pytest.raises(ObjectsError):
        frame(tracking, 1.0, mask=np.zeros((3, 3), np.uint8))
    update = frame(tracking, 1.1)
    assert [(o.id, o.state) for o in update.objects] == [(first, "confirmed")]
