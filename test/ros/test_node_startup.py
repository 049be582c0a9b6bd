"""Start-up with invalid parameter values: the node process refuses with one line, exit 2."""

import subprocess
import sys

import pytest
import rclpy
from rclpy.parameter import Parameter

from allo_mrad_ros.ros.arguments import command_line_parameters
from allo_mrad_ros.ros.node import EXIT_INVALID_PARAMETER, MradDetectorNode

pytestmark = pytest.mark.ros


def run_node(*arguments: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "allo_mrad_ros.ros.node", "--ros-args", *arguments],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.parametrize(
    ("parameter", "expected"),
    [
        ("mrad.grid:=0", "mrad.grid must be an integer in [1, 64], got 0"),
        ("reference_scale:=0.0", "reference_scale must be in [0.05, 1], got 0.0"),
        ("mrad.tolerance:=.nan", "mrad.tolerance must be finite, got nan"),
        ("diagnostics_period_s:=0.0", "diagnostics_period_s must be in [0.1, 60], got 0.0"),
        ("mrad.grid:=abc", "mrad.grid must be a number, got 'abc'"),
        ("mrad.kernel_fraction:=0.0", "mrad.kernel_fraction must be in (0, 1], got 0.0"),
        ("sun_direction:=[1e300,1e300,.nan]", "sun_direction must be finite"),
    ],
)
def test_invalid_value_refuses_to_start_with_one_line_naming_it(parameter, expected):
    done = run_node("-p", "pose_source:=topic", "-p", parameter)
    assert done.returncode == EXIT_INVALID_PARAMETER, done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and expected in lines[0], done.stderr


def _cuda_visible() -> bool:
    try:
        import torch
    except ImportError:
        return False
    return torch.cuda.is_available()


def test_an_array_backend_this_machine_cannot_run_refuses_to_start_with_the_reason():
    if _cuda_visible():
        pytest.skip("this machine can run the CUDA backend")
    # Without PyTorch the reason is the missing library, with it the missing GPU.
    done = run_node("-p", "pose_source:=topic", "-p", "array_backend:=torch:cuda")
    assert done.returncode == EXIT_INVALID_PARAMETER, done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "array_backend 'torch:cuda' needs" in lines[0], done.stderr
    unknown = run_node("-p", "pose_source:=topic", "-p", "array_backend:=cupy")
    assert unknown.returncode == EXIT_INVALID_PARAMETER, unknown.stderr
    assert "array_backend must be one of" in unknown.stderr


def test_command_line_value_is_checked_even_where_a_params_file_sets_it(tmp_path):
    # rcl keeps the file's value when -p gives another type: that must not pass silently.
    params = tmp_path / "params.yaml"
    params.write_text(
        "/**:\n  ros__parameters:\n    pose_source: topic\n    mrad:\n      grid: 8\n"
    )
    done = run_node("--params-file", str(params), "-p", "mrad.grid:=abc")
    assert done.returncode == EXIT_INVALID_PARAMETER, done.stderr
    assert "mrad.grid must be a number, got 'abc'" in done.stderr


def test_a_missing_mesh_file_refuses_to_start_in_one_line():
    done = run_node("-p", "pose_source:=topic", "-p", "mesh:=/nonexistent/station.glb")
    assert done.returncode == EXIT_INVALID_PARAMETER, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "mesh must be an existing model file" in lines[0], done.stderr


@pytest.mark.parametrize(
    ("content", "expected"),
    [(None, "No such file or directory"), ("/**:\n  ros__parameters: [x\n", "invalid YAML")],
)
def test_a_missing_or_malformed_params_file_is_one_line(tmp_path, content, expected):
    params = tmp_path / "params.yaml"
    if content is not None:
        params.write_text(content)
    done = run_node("--params-file", str(params))
    assert done.returncode == EXIT_INVALID_PARAMETER, done.stderr
    assert "Traceback" not in done.stderr and "[rcl]" not in done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and f"params file {params}: {expected}" in lines[0], done.stderr


def test_an_unknown_parameter_name_is_warned_about_with_the_closest_name(capfd):
    from allo_mrad_ros.ros.arguments import unknown_parameters

    declared = ["mrad.grid", "reference_scale", "pose_source"]
    given = ["mrad.gird", "use_sim_time", "qos_overrides./x.subscription.depth", "mrad.grid"]
    assert unknown_parameters(given, declared) == [
        "unknown parameter mrad.gird ignored; did you mean mrad.grid?"
    ]
    rclpy.init()
    try:
        node = MradDetectorNode(
            parameter_overrides=[
                Parameter("pose_source", value="topic"),
                Parameter("mrad.gird", value=4),
            ]
        )
        node.destroy_node()
    finally:
        rclpy.shutdown()
    assert "unknown parameter mrad.gird ignored; did you mean mrad.grid?" in capfd.readouterr().err


def test_command_line_parameters_are_read_as_yaml_from_ros_args_only():
    argv = ["node", "-p", "x:=1", "--ros-args", "-p", "a:=2", "--param", "b:=[1, 2.5]", "--"]
    assert command_line_parameters(argv) == {"a": 2, "b": [1, 2.5]}


def test_an_integer_for_a_float_parameter_is_used_and_reported_as_the_float():
    rclpy.init()
    try:
        node = MradDetectorNode(
            parameter_overrides=[
                Parameter("pose_source", value="topic"),
                Parameter("mrad.tolerance", value=60),
            ]
        )
        try:
            value = node.get_parameter("mrad.tolerance").value
            assert value == 60.0 and isinstance(value, float)
            assert node._config.pipeline.params.tolerance == 60.0
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()
