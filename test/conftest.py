"""Test-wide settings: headless OpenGL and ROS traffic confined to this machine.

`make test` also runs pytest in a private network namespace where the machine allows it;
these variables keep DDS on loopback everywhere else too, for in-process rclpy and for
every subprocess a test starts.
"""

import importlib.util
import os
import re
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
os.environ.setdefault(
    "FASTDDS_DEFAULT_PROFILES_FILE", str(REPO / "config" / "fastdds_loopback.xml")
)
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
# A domain of its own per test run, so parallel runs on one machine do not hear each other.
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))

# `make test-distro` runs the suite in a venv shaped like a ROS distro's Python without a ROS
# install (no rclpy): modules that need rclpy at import are left out there, not failed.
if importlib.util.find_spec("rclpy") is None:
    collect_ignore = [
        str(path.relative_to(REPO / "test"))
        for path in (REPO / "test").rglob("test_*.py")
        if re.search(r"^(import|from) rclpy\b", path.read_text(), re.MULTILINE)
    ]
