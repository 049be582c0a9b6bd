"""A renderer rebuilt for every new camera (camera_info changing) releases what it made."""

from __future__ import annotations

import ctypes
import ctypes.util
import gc

import numpy as np
import psutil
import pytest
import trimesh

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.resources import share_path

# Two cameras alternating, as camera_info of two sizes on one topic makes the node do.
CAMERAS = (
    CameraIntrinsics(32, 18, 22.2, 22.2, 16.0, 9.0),
    CameraIntrinsics(34, 18, 22.2, 22.2, 17.0, 9.0),
)
POSE = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
SUN = (0.3, -0.5, 0.8)
# Rebuilds before RSS is first read (the first GL context, shader compilers and allocator
# arenas settle), rebuilds measured after, and rebuilds between two readings.
WARM_UP, MEASURED, INTERVAL = 50, 150, 25
# Unreleased, each rebuild of the station's renderer kept about 27 KB (the pointers PyOpenGL
# stored for its vertex arrays); released, under 6 KB stays (Mesa's own, measured with
# OSMesa). The bound lies between, with room for allocator noise.
BOUND_KB_PER_REBUILD = 12.0


@pytest.fixture(scope="module")
def station() -> trimesh.Scene:
    return trimesh.load(share_path("meshes", "station.glb"))


def _rebuild(model: object, camera: CameraIntrinsics) -> None:
    with ReferenceRenderer(model, camera, scale=1.0) as renderer:
        renderer.render(POSE, SUN)


def test_a_closed_renderer_leaves_nothing_in_pyopengls_context_storage(station):
    from OpenGL import contextdata

    def stored() -> int:
        return sum(len(storage) for storage in contextdata.STORAGES)

    before = stored()
    for camera in CAMERAS * 3:
        _rebuild(station, camera)
    # At most what was there: renderers of earlier tests may release theirs meanwhile (their
    # finalisers run when the collector gets to them), so the count can also fall.
    assert stored() <= before


def _resident_kb(libc: ctypes.CDLL | None) -> float:
    """RSS after returning freed heap to the system (so free blocks are not counted)."""
    gc.collect()
    if libc is not None:
        libc.malloc_trim(0)
    return psutil.Process().memory_info().rss / 1024


@pytest.mark.slow
def test_hundreds_of_rebuilds_keep_resident_memory_bounded(station):
    name = ctypes.util.find_library("c")
    libc = ctypes.CDLL(name) if name and hasattr(ctypes.CDLL(name), "malloc_trim") else None
    for index in range(WARM_UP):
        _rebuild(station, CAMERAS[index % 2])
    samples = [_resident_kb(libc)]
    for index in range(MEASURED):
        _rebuild(station, CAMERAS[index % 2])
        if index % INTERVAL == INTERVAL - 1:
            samples.append(_resident_kb(libc))
    # A leak grows every interval alike; an allocator grows its pools in steps now and then.
    per_rebuild = float(np.median(np.diff(samples))) / INTERVAL
    assert per_rebuild < BOUND_KB_PER_REBUILD, (
        f"{per_rebuild:.1f} KB per rebuild; RSS every {INTERVAL} rebuilds: {np.round(samples)} KB"
    )
