"""The launch argument ``log_level`` sets the node's own logger, not rcl's or the middleware's:
checked with rclpy's own parsing of the ``--ros-args`` the launch file gives the node."""

import subprocess
import sys

import pytest

from allo_mrad_ros.ros.launch_arguments import ros_arguments

pytestmark = pytest.mark.ros
# The probe runs rclpy in a child process: absent here (make test-distro), nothing to check.
pytest.importorskip("rclpy", reason="rclpy is not installed")

PROBE = """
import sys, rclpy
rclpy.init(args=sys.argv[2:])
node = rclpy.create_node("mrad_detector", namespace=sys.argv[1])
node.get_logger().debug("the node's own debug line")
node.destroy_node()
rclpy.shutdown()
"""


def debug_lines(arguments: list[str], namespace: str) -> list[str]:
    """The DEBUG lines of a node named as ours, started with ``arguments``."""
    done = subprocess.run(
        [sys.executable, "-c", PROBE, namespace, *arguments],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return [line for line in (done.stdout + done.stderr).splitlines() if "[DEBUG]" in line]


@pytest.mark.parametrize("namespace", ["", "arm2"])
def test_log_level_debug_turns_on_the_nodes_debug_lines_only(namespace):
    lines = debug_lines(ros_arguments("debug", namespace), f"/{namespace}")
    logger = f"{namespace}.mrad_detector" if namespace else "mrad_detector"
    assert any(f"[{logger}]: the node's own debug line" in line for line in lines), lines
    assert all(f"[{logger}]" in line for line in lines), lines[:5]
    # The oracle: the bare form also turns rcl's on, what the launch file must not do.
    bare = debug_lines(["--ros-args", "--log-level", "debug"], f"/{namespace}")
    assert any("[rcl]" in line for line in bare)
