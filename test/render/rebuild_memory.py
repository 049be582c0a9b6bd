"""Resident memory of a process that rebuilds the station's renderer again and again.

Run by ``test_renderer_memory.py`` as a process of its own: a fresh interpreter's heap holds
only the renderer's objects, so each rebuild's garbage collection is quick and the resident
set is not moved by what earlier tests left. Prints one JSON object: the resident set (KB)
after the warm-up and after every ``interval`` measured rebuilds.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import gc
import json

import psutil
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


def rebuild(model: trimesh.Scene, camera: CameraIntrinsics) -> None:
    """Build a renderer for ``camera``, render one frame and close it."""
    with ReferenceRenderer(model, camera, scale=1.0) as renderer:
        renderer.render(POSE, SUN)


def resident_kb(libc: ctypes.CDLL | None) -> float:
    """RSS after returning freed heap to the system (so free blocks are not counted)."""
    gc.collect()
    if libc is not None:
        libc.malloc_trim(0)
    return psutil.Process().memory_info().rss / 1024


def measure(warm_up: int, measured: int, interval: int) -> list[float]:
    """The resident set after ``warm_up`` rebuilds and after every ``interval`` of the
    ``measured`` rebuilds that follow."""
    name = ctypes.util.find_library("c")
    libc = ctypes.CDLL(name) if name and hasattr(ctypes.CDLL(name), "malloc_trim") else None
    station = trimesh.load(share_path("meshes", "station.glb"))
    for index in range(warm_up):
        rebuild(station, CAMERAS[index % 2])
    samples = [resident_kb(libc)]
    for index in range(measured):
        rebuild(station, CAMERAS[index % 2])
        if index % interval == interval - 1:
            samples.append(resident_kb(libc))
    return samples


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warm-up", type=int, required=True)
    parser.add_argument("--measured", type=int, required=True)
    parser.add_argument("--interval", type=int, required=True)
    args = parser.parse_args()
    print(json.dumps({"rss_kb": measure(args.warm_up, args.measured, args.interval)}))
