"""Tests of the procedural anomaly objects and ALLO's placement rules."""

from __future__ import annotations

import numpy as np
import pytest

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.synth import placement
from allo_mrad_ros.synth.objects import ANOMALY_TYPES, SHEET_TYPES, ObjectError, build_anomaly
from allo_mrad_ros.synth.occupancy import StationOccupancy


@pytest.fixture(scope="module")
def occupancy():
    return StationOccupancy.from_model(None)


@pytest.mark.parametrize("kind", list(ANOMALY_TYPES))
def test_each_object_type_builds_a_plausible_mesh(kind):
    assert len(ANOMALY_TYPES) >= 12
    for seed in range(4):
        obj = build_anomaly(kind, seed)
        assert obj.parts and all(len(p.mesh.faces) > 0 for p in obj.parts)
        for part in obj.parts:
            mesh = part.mesh
            if kind in SHEET_TYPES:
                # An open sheet: every edge on one or two faces, with a boundary.
                counts = np.bincount(mesh.edges_unique_inverse)
                assert counts.max() <= 2 and counts.min() == 1
            else:
                assert mesh.is_watertight and mesh.volume > 0
        extents = obj.extents
        assert 0.1 <= extents.max() <= 3.0, extents
        np.testing.assert_allclose(obj.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)
        assert len(obj.scene.geometry) == len(obj.parts)
    again = build_anomaly(kind, 1)
    np.testing.assert_array_equal(again.mesh.vertices, build_anomaly(kind, 1).mesh.vertices)
    assert not np.array_equal(again.mesh.vertices, build_anomaly(kind, 2).mesh.vertices)


def test_object_errors_and_colour_variants():
    with pytest.raises(ObjectError):
        build_anomaly("spoon", 0)
    with pytest.raises(ObjectError):
        build_anomaly("drill", 0, "plaid")
    with pytest.raises(ObjectError):
        build_anomaly("drill", -1)
    red = build_anomaly("drill", 0, "red")
    first = next(iter(red.scene.geometry.values()))
    assert tuple(first.visual.material.baseColorFactor[:3]) != tuple(
        next(
            iter(build_anomaly("drill", 0).scene.geometry.values())
        ).visual.material.baseColorFactor[:3]
    )


def test_placement_rules_reject_bad_candidates(occupancy):
    k = CameraIntrinsics(320, 180, 222.2, 222.2, 160, 90)
    camera = look_at([0.0, -30.0, 0.0], [0.0, 0.0, 0.0])
    obj = build_anomaly("cubesat_3u", 0)

    def at(position):
        pose = np.eye(4)
        pose[:3, 3] = position
        return placement.check(obj, pose, camera, k, occupancy, 0.5)

    assert at([0.0, -26.0, 0.0]).rejected == ""
    assert at([0.0, 0.0, 0.0]).rejected == "station"  # inside the habitation module
    assert at([0.0, 10.0, 0.0]).rejected == "occluded"  # behind it
    assert at([30.0, -26.0, 0.0]).rejected == "frustum"
    assert at([0.0, -29.9, 0.0]).rejected == "range"
    rng = np.random.default_rng(0)
    for depth in (-2.0, 2.0):
        pose = placement.propose(camera, rng, 4.0, 1.2, depth)
        offset = camera[:3, :3].T @ (pose[:3, 3] - camera[:3, 3])
        assert np.all(np.abs(offset - [0, 0, 4.0 + depth]) <= 1.2)
