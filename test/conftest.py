"""Test-wide settings: headless OpenGL and ROS traffic confined to this machine.

`make test` also runs pytest in a private network namespace where the machine allows it;
these variables keep DDS on loopback everywhere else too, for in-process rclpy and for
every subprocess a test starts.
"""

import gc
import importlib.util
import os
import re
from pathlib import Path

from hypothesis import HealthCheck, settings

from allo_mrad_ros.ros.node_process import use_loopback_profile
from harness.dds import WORKER_DOMAIN_STEP, current_domain, domain_apart, process_domain
from harness.shared_memory import present, remove_orphans

REPO = Path(__file__).resolve().parent.parent

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
# Under the variable this Fast DDS reads (Jazzy's 2.x reads another than Kilted's 3.x).
use_loopback_profile(profile=REPO / "config" / "fastdds_loopback.xml")
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
# A domain of its own per test run (harness.dds), so parallel runs do not hear each other.
os.environ.setdefault("ROS_DOMAIN_ID", str(process_domain()))
# Under pytest-xdist each worker (gw0, gw1, ...) inherits the run's domain and takes one of its
# own, WORKER_DOMAIN_STEP apart from the next worker's.
if os.environ.get("PYTEST_XDIST_WORKER", "").startswith("gw"):
    _worker = int(os.environ["PYTEST_XDIST_WORKER"][2:])
    os.environ["ROS_DOMAIN_ID"] = str(
        domain_apart(current_domain(), WORKER_DOMAIN_STEP * (_worker + 1))
    )

# Property tests: `make test` draws the same few examples on every run (a CI run must not
# fail by chance); `make fuzz` (ALLO_FUZZ=1) draws many new ones each time.
_UNTIMED = {
    "deadline": None,
    "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large],
}
settings.register_profile(
    "fuzz", max_examples=int(os.environ.get("ALLO_FUZZ_EXAMPLES", "300")), **_UNTIMED
)
settings.register_profile("quick", max_examples=20, derandomize=True, **_UNTIMED)
settings.load_profile("fuzz" if os.environ.get("ALLO_FUZZ") else "quick")

# `make test-distro` runs the suite in a venv shaped like a ROS distro's Python without a ROS
# install (no rclpy): modules that need rclpy at import are left out there, not failed.
if importlib.util.find_spec("rclpy") is None:
    collect_ignore = [
        str(path.relative_to(REPO / "test"))
        for path in (REPO / "test").rglob("test_*.py")
        if re.search(r"^(import|from) rclpy\b", path.read_text(), re.MULTILINE)
    ]

# `make test-jazzy` (ALLO_TESTS=ros) runs only what touches ROS on the Jazzy wheels: the node's
# tests and every module that names rclpy, a message package, launch_ros or tf2_ros; the rest
# is the Python the main and distro stages already run.
ROS_TESTS = re.compile(r"\b(rclpy|[a-z0-9_]+_msgs|launch_ros|tf2_ros)\b")


def touches_ros(path: Path) -> bool:
    """Whether test module ``path`` is one of the Jazzy stage's."""
    return path.parent == REPO / "test" / "ros" or bool(ROS_TESTS.search(path.read_text()))


if os.environ.get("ALLO_TESTS") == "ros":
    collect_ignore = [
        str(path.relative_to(REPO / "test"))
        for path in (REPO / "test").rglob("test_*.py")
        if not touches_ros(path)
    ]


_SHARED_MEMORY_BEFORE: frozenset[str] = frozenset()


def pytest_sessionstart(session):
    """Note the Fast DDS shared-memory files there before the run (harness.shared_memory)."""
    global _SHARED_MEMORY_BEFORE
    _SHARED_MEMORY_BEFORE = present()


def pytest_collection_finish(session):
    """Move what collection made (every module the tests import, the test items) out of the
    collector's reach: a full collection, which each closed renderer asks for (pyrender
    collects before deleting its context), then walks only what the tests make. Those
    objects live for the whole run anyway."""
    gc.collect()
    gc.freeze()


def pytest_sessionfinish(session, exitstatus):
    """Delete the Fast DDS shared-memory files this run's killed processes left in /dev/shm
    (memory): those made since the session started that no live process uses."""
    remove_orphans(keep=_SHARED_MEMORY_BEFORE)
