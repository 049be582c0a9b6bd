"""What the object tests share: a small camera, regions made where points project, and a
camera that sweeps past a scene at a fixed orientation."""

from __future__ import annotations

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector.regions import Region
from allo_mrad_ros.geometry import look_at

CAMERA = CameraIntrinsics(width=640, height=480, fx=500.0, fy=500.0, cx=319.5, cy=239.5)
# The reference at an eighth of the image, as the default reference scale renders it.
DEPTH_SHAPE = (60, 80)
SPACE = np.zeros(DEPTH_SHAPE, np.float32)


def region_at(u: float, v: float, extent: int = 8, score: float = 0.9) -> Region:
    """A region centred on pixel ``(u, v)`` with a square box of side ``extent``."""
    x, y = round(u - extent / 2), round(v - extent / 2)
    box = (x, y, extent, extent)
    return Region(
        box=box,
        area=extent * extent,
        centroid=(float(u), float(v)),
        work_box=box,
        work_area=extent * extent,
        peak_score=200.0,
        mean_score=150.0,
        score=score,
    )


def project(point: np.ndarray, pose: np.ndarray, camera: CameraIntrinsics = CAMERA):
    """``(u, v, z)`` of a station-frame point seen from ``pose``."""
    local = pose[:3, :3].T @ (np.asarray(point, float) - pose[:3, 3])
    return (
        camera.fx * local[0] / local[2] + camera.cx,
        camera.fy * local[1] / local[2] + camera.cy,
        local[2],
    )


def sweep(t: float, speed: float = 0.2, start=(-2.0, -10.0, 0.0), look=(0.0, 1.0, 0.0)):
    """A camera moving along x at ``speed`` m/s, looking along ``look`` (station frame)."""
    eye = np.asarray(start, float) + np.array([speed * t, 0.0, 0.0])
    return look_at(eye, eye + np.asarray(look, float))


def wall_depth(z: float, shape=DEPTH_SHAPE) -> np.ndarray:
    """A fronto-parallel wall at z depth ``z`` filling the view."""
    return np.full(shape, z, np.float32)


# The scenes of the rule tests were built for these values (2 px centroids, a 4-sigma gate,
# 3-sigma parallax over a slow sweep, every region taken, objects from 0.3 m): the tests pin
# them, so that a change of the shipped defaults (chosen on data) does not change the scenes.
SCENE_PARAMS = {
    "pixel_sigma": 2.0,
    "min_range": 0.3,
    "gate_sigma": 4.0,
    "parallax_sigma": 3.0,
    "min_region_score": 0.0,
    # Noise-free camera positions, regions inside the image.
    "position_sigma": 0.0,
    "edge_sigma_fraction": 0.0,
}


def scene_params(**changes):
    """:class:`ObjectParams` of :data:`SCENE_PARAMS` with ``changes``."""
    from allo_mrad_ros.objects import ObjectParams

    return ObjectParams(**{**SCENE_PARAMS, **changes})
