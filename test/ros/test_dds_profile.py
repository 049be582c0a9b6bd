"""The loopback profile reaches the Fast DDS that rclpy loads, whichever major version it is.

Fast DDS 3 (Kilted) reads ``FASTDDS_DEFAULT_PROFILES_FILE``; Fast DDS 2 (Humble, Jazzy) reads
only ``FASTRTPS_DEFAULT_PROFILES_FILE``. Without the profile, Fast DDS's 512 KB shared-memory
segment drops about half of the 640x360 images between two processes (Jazzy's wheels, idle).
"""

import os
import re
import select
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from allo_mrad_ros.ros.node_process import PROFILE_VARIABLES, fast_dds_major, use_loopback_profile

pytestmark = pytest.mark.ros

NEW, OLD = PROFILE_VARIABLES[3], PROFILE_VARIABLES[2]


def test_the_profile_goes_under_the_name_each_fast_dds_reads():
    environ = {NEW: "/given.xml"}
    assert use_loopback_profile(environ, Path("/loopback.xml"), major=2) == OLD
    assert environ == {NEW: "/given.xml", OLD: "/given.xml"}  # the one given, not ours
    environ = {}
    assert use_loopback_profile(environ, Path("/loopback.xml"), major=3) == NEW
    assert environ == {NEW: "/loopback.xml"}  # Fast DDS 3 warns when the old name is set
    environ = {OLD: "/old.xml"}
    use_loopback_profile(environ, Path("/loopback.xml"), major=3)
    assert environ == {OLD: "/old.xml", NEW: "/old.xml"}


def test_fast_dds_major_is_the_library_rclpy_loaded():
    maps = Path("/proc/self/maps")
    if not maps.exists():
        pytest.skip("no /proc/self/maps here")
    rclpy.init()
    try:
        node = rclpy.create_node("allo_profile_probe")  # loads the middleware
        node.destroy_node()
    finally:
        rclpy.shutdown()
    loaded = set(re.findall(r"lib(fastdds|fastrtps)\.so\.(\d+)", maps.read_text()))
    assert loaded, "no Fast DDS library in this process"
    assert {int(major) for _, major in loaded} == {fast_dds_major()}
    assert os.environ.get(PROFILE_VARIABLES[fast_dds_major()])  # test/conftest.py set it


SUBSCRIBER = """
import rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
rclpy.init()
node = rclpy.create_node("allo_profile_subscriber")
got = lambda msg: print("got", msg.header.stamp.sec, flush=True)
subscription = node.create_subscription(Image, "/allo_profile_probe", got, qos_profile_sensor_data)
while subscription.get_publisher_count() == 0:
    rclpy.spin_once(node, timeout_sec=0.05)
print("matched", flush=True)
rclpy.spin(node)  # until killed
"""


def test_images_over_the_default_shared_memory_segment_cross_between_processes():
    rclpy.init()
    node = rclpy.create_node("allo_profile_publisher")
    publisher = node.create_publisher(Image, "/allo_profile_probe", qos_profile_sensor_data)
    child = subprocess.Popen([sys.executable, "-c", SUBSCRIBER], stdout=subprocess.PIPE, text=True)

    def line(timeout: float) -> str:
        """The subscriber's next line ("" if none comes within ``timeout`` seconds)."""
        ready, _, _ = select.select([child.stdout], [], [], timeout)
        return child.stdout.readline().strip() if ready else ""

    try:
        # Both sides matched: the child's reader ours (it says so) and our writer its reader
        # (discovery runs on each side apart; a best-effort writer that has not matched the
        # reader yet sends to nobody). From then on an image is dropped only by the transport.
        assert line(60.0) == "matched"
        deadline = time.monotonic() + 60.0
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert publisher.get_subscription_count() == 1, "our writer never matched the reader"
        image = Image(width=640, height=360, encoding="rgb8", step=1920)
        image.data = bytes(1920 * 360)  # 691 kB: over Fast DDS's default 512 kB segment
        for index in range(5):
            image.header.stamp.sec = index
            publisher.publish(image)
            assert line(10.0) == f"got {index}", f"image {index} of 5 was lost"
    finally:
        child.kill()
        child.wait()
        node.destroy_node()
        rclpy.shutdown()
