"""The one place that reads rclpy's private state, checked against the rclpy installed.

The CI runs this on its rclpy (Kilted wheels); the distro route without rclpy skips the file.
If rclpy moves or changes the overrides, these fail here rather than the node reading nothing.
"""

from __future__ import annotations

import time
import types

import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.subscription import Subscription

from allo_mrad_ros.ros.rclpy_compat import (
    RclpyCompatError,
    message_info_callback,
    parameter_overrides,
)

pytestmark = pytest.mark.ros


@pytest.fixture
def context():
    context = rclpy.Context()
    rclpy.init(context=context, args=["prog", "--ros-args", "-p", "from_command_line:=7"])
    yield context
    rclpy.shutdown(context=context)


def test_overrides_from_the_command_line_and_the_constructor_are_read(context):
    node = rclpy.create_node(
        "compat_test",
        context=context,
        parameter_overrides=[Parameter("given", value=2.5)],
        automatically_declare_parameters_from_overrides=False,
    )
    try:
        overrides = parameter_overrides(node)
        assert overrides["from_command_line"].value == 7
        assert overrides["given"].value == 2.5
        assert set(overrides) == {"from_command_line", "given"}
        # What rclpy applies on declaration is what the shim reads.
        assert node.declare_parameter("given", 0.0).value == 2.5
        assert node.declare_parameter("from_command_line", 0).value == 7
    finally:
        node.destroy_node()


def test_a_node_without_overrides_gives_an_empty_mapping_that_cannot_be_changed():
    context = rclpy.Context()
    rclpy.init(context=context, args=["prog"])
    node = rclpy.create_node("compat_empty", context=context)
    try:
        overrides = parameter_overrides(node)
        assert dict(overrides) == {}
        with pytest.raises(TypeError):
            overrides["x"] = Parameter("x", value=1)  # type: ignore[index]
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def test_an_rclpy_that_keeps_them_elsewhere_is_named_not_read_as_empty():
    with pytest.raises(RclpyCompatError, match="_parameter_overrides is NoneType"):
        parameter_overrides(types.SimpleNamespace())


def test_a_message_info_callback_gets_when_each_message_was_sent_where_rclpy_says_it(context):
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    node = rclpy.create_node("compat_info", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    got = []
    try:
        node.create_subscription(
            String, "compat_info", message_info_callback(lambda m, i: got.append((m, i))), 10
        )
        publisher = node.create_publisher(String, "compat_info", 10)
        before_ns = time.time_ns()
        # Discovery takes a moment: published again until one arrives (60 s: a bound for a
        # loaded machine, not a measured time).
        deadline = time.monotonic() + 60.0
        while not got and time.monotonic() < deadline:
            publisher.publish(String(data="x"))
            executor.spin_once(timeout_sec=0.05)
        assert got and got[0][0].data == "x"
        info = got[0][1]
        if hasattr(Subscription, "CallbackType"):  # Iron and later: the middleware's times
            assert before_ns <= info["source_timestamp"] <= time.time_ns()
            assert info["source_timestamp"] <= info["received_timestamp"] <= time.time_ns()
        else:  # Humble passes none
            assert info is None
    finally:
        executor.shutdown()
        node.destroy_node()
