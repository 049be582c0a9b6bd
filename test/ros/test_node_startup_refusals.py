"""Start-up refusals and warnings: bad mesh, params files, empty values, QoS overrides, TF.

Each refusal is one line on stderr and exit 2; what the node cannot apply it says.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy

from allo_mrad_ros.ros.arguments import check_command_line, check_params_files, keys_for_other_nodes
from allo_mrad_ros.ros.node import EXIT_INVALID_PARAMETER, MradDetectorNode
from allo_mrad_ros.ros.parameters import ParameterError
from allo_mrad_ros.ros.pose_source import tf2_available

pytestmark = pytest.mark.ros


def run_node(*arguments: str, timeout: float = 180.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "allo_mrad_ros.ros.node", "--ros-args", *arguments],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def refused_in_one_line(done: subprocess.CompletedProcess, expected: str) -> None:
    assert done.returncode == EXIT_INVALID_PARAMETER, done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and expected in lines[0], done.stderr


@pytest.mark.parametrize("content", [b"", b"solid garbage\x00\x01 not a model at all"])
def test_a_zero_byte_or_garbage_mesh_refuses_to_start(tmp_path, content):
    mesh = tmp_path / "station.glb"
    mesh.write_bytes(content)
    done = run_node("-p", "pose_source:=topic", "-p", f"mesh:={mesh}")
    refused_in_one_line(done, "is not a usable model")


def test_a_params_file_without_ros__parameters_is_one_line(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text("/**:\n  pose_source: topic\n")
    with pytest.raises(ParameterError, match="has no ros__parameters"):
        check_params_files(["--ros-args", "--params-file", str(params)])
    refused_in_one_line(run_node("--params-file", str(params)), "has no ros__parameters")


def test_an_empty_command_line_value_is_one_line():
    with pytest.raises(ParameterError, match="mesh:= has no value"):
        check_command_line(["x", "--ros-args", "-p", "mesh:="])
    check_command_line(["x", "--ros-args", "-p", "mesh:=''", "-p", "a:=1"])
    refused_in_one_line(
        run_node("-p", "pose_source:=topic", "-p", "mesh:="), "-p mesh:= has no value"
    )


def test_a_params_file_for_another_node_name_is_warned_about(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text("other_node:\n  ros__parameters:\n    mrad:\n      grid: 4\n")
    files = check_params_files(["--ros-args", "--params-file", str(params)])
    assert files == {params: ["other_node"]}
    (warning,) = keys_for_other_nodes(files, "/mrad_detector")
    assert "other_node" in warning and "ignored" in warning
    for key in ("/**", "mrad_detector", "/mrad_detector", "/**/mrad_detector", "/*"):
        assert keys_for_other_nodes({params: [key]}, "/mrad_detector") == [], key
    assert keys_for_other_nodes({params: ["/arm2/mrad_detector"]}, "/arm2/mrad_detector") == []
    assert keys_for_other_nodes({params: ["/arm1/mrad_detector"]}, "/arm2/mrad_detector")


def test_the_node_logs_the_other_node_warning(tmp_path, capfd):
    params = tmp_path / "params.yaml"
    params.write_text("other_node:\n  ros__parameters:\n    mrad:\n      grid: 4\n")
    files = check_params_files(["--params-file", str(params)])
    rclpy.init()
    try:
        node = MradDetectorNode(
            {}, files, parameter_overrides=[Parameter("pose_source", value="topic")]
        )
        node.destroy_node()
    finally:
        rclpy.shutdown()
    assert "sets parameters for other_node, not for this node" in capfd.readouterr().err


def _node(*overrides: Parameter) -> MradDetectorNode:
    return MradDetectorNode(
        parameter_overrides=[Parameter("pose_source", value="topic"), *overrides]
    )


def test_a_durability_qos_override_is_applied():
    rclpy.init()
    try:
        node = _node(
            Parameter(
                "qos_overrides./mrad_detector/mask.publisher.durability", value="transient_local"
            )
        )
        try:
            assert node._outputs.mask.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()


def test_a_qos_override_nothing_applies_is_refused():
    rclpy.init()
    try:
        name = "qos_overrides./mrad_detector/mask.publisher.durabilty"
        with pytest.raises(ParameterError, match="durabilty match no publisher"):
            _node(Parameter(name, value="transient_local"))
    finally:
        rclpy.shutdown()


def test_pose_source_tf_without_the_tf2_module_refuses_to_start():
    if tf2_available():
        pytest.skip("tf2_ros is installed here")
    refused_in_one_line(run_node("-p", "pose_source:=tf"), "tf2_ros_py")


def test_mesh_load_is_checked_in_process_too(tmp_path: Path):
    mesh = tmp_path / "empty.obj"
    mesh.write_bytes(b"")
    rclpy.init()
    try:
        with pytest.raises(ParameterError, match=r"mesh .*is not a usable model"):
            _node(Parameter("mesh", value=str(mesh)))
    finally:
        rclpy.shutdown()
