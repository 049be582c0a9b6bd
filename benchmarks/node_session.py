"""The running node and a camera feed, as the node benchmarks drive it.

:func:`node_session` starts ``mrad_detector`` as its own process and a
:class:`~harness.feed.CameraFeed` in this one, on loopback DDS; :func:`still_frames` renders
the still pose's two images (clean, and with a pasted object) that the feeds publish in turn
under :data:`SUN`. Shared by ``bench-node``, its output comparison, the profiler and the flood.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import psutil
import rclpy

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.example_scene import paste_object
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.ros.node_process import start_node, stop_node, use_loopback_profile
from allo_mrad_ros.ros.process_tuning import keep_freed_memory
from harness.feed import CameraFeed

SUN = (0.3, -0.5, 0.8)
"""The Sun direction the feeds publish with every frame (station frame)."""


def still_frames(
    camera: CameraIntrinsics = ALLO_INTRINSICS,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The still pose and its two images: the render, and the render with a pasted object."""
    pose = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
    with ReferenceRenderer(None, camera, scale=1.0) as renderer:
        clean = renderer.render(pose, SUN).rgb
    with_object, _ = paste_object(clean, seed=1, centre=(0.5, 0.15), size=0.08)
    return pose, [clean, with_object]


@contextmanager
def node_session(
    log_path: Path, feed_options: dict, *node_args: str, camera: CameraIntrinsics = ALLO_INTRINSICS
) -> Iterator[tuple[CameraFeed, psutil.Process]]:
    """Start the node and a camera feed on loopback DDS; stop both whatever happens.

    Parameters
    ----------
    log_path : Path
        Where the node's output goes.
    feed_options : dict
        Keyword options of :class:`~harness.feed.CameraFeed` besides the camera.
    *node_args : str
        The node's ``name:=value`` parameters.
    camera : CameraIntrinsics
        The feed's camera.
    """
    use_loopback_profile()
    # The feed stands for a camera driver and a viewer, C++ programs that reuse their
    # buffers; without this its Python receives would fault in pages the node competes for.
    keep_freed_memory(512)
    rclpy.init()
    feed = CameraFeed(camera, keep_messages=False, **feed_options)
    process = start_node(log_path, *node_args)
    try:
        if not feed.wait_for_node(60.0):
            raise RuntimeError(f"node did not subscribe; see {log_path}")
        yield feed, psutil.Process(process.pid)
        if process.poll() is not None:
            raise RuntimeError(f"node exited with {process.returncode}; see {log_path}")
    finally:
        stop_node(process)
        feed.node.destroy_node()
        rclpy.shutdown()
