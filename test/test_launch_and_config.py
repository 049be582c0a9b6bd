"""The launch file names only things the package installs; the config file is valid."""

import ast
import importlib
import importlib.util
import re
from pathlib import Path

import pytest
import yaml

from allo_mrad_ros.ros.parameters import detector_parameters, node_parameters, validate

REPO = Path(__file__).resolve().parent.parent
LAUNCH_FILE = REPO / "launch" / "detect.launch.py"


def console_scripts():
    text = (REPO / "setup.py").read_text()
    return dict(re.findall(r'"([\w-]+) = ([\w.]+:\w+)"', text))


def launch_tree():
    return ast.parse(LAUNCH_FILE.read_text())


def node_calls(tree):
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, "id", None) == "Node":
            yield {k.arg: k.value for k in call.keywords}


def test_every_executable_of_this_package_is_an_installed_console_script():
    pytest.importorskip("rclpy", reason="the node module needs rclpy")
    scripts = console_scripts()
    names = []
    for keywords in node_calls(launch_tree()):
        package = keywords["package"]
        if isinstance(package, ast.Name) and package.id == "PACKAGE":
            executable = keywords["executable"].value
            names.append(executable)
            assert executable in scripts, f"{executable} is not a console script in setup.py"
            module, function = scripts[executable].split(":")
            assert hasattr(importlib.import_module(module), function)
    assert names == ["mrad_detector"]


def test_every_package_file_the_launch_file_names_exists_and_is_installed():
    tree = launch_tree()
    named = []
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, "id", None) == "PathJoinSubstitution":
            parts = [e.value for e in call.args[0].elts if isinstance(e, ast.Constant)]
            named.append(Path(*parts))
    assert Path("config", "mrad.yaml") in named and Path("config", "mrad.rviz") in named
    setup = (REPO / "setup.py").read_text()
    for path in named:
        assert (REPO / path).is_file(), path
        assert f'_files("{path.parts[0]}/*")' in setup, f"{path.parts[0]}/ is not installed"


def flatten(parameters, prefix=""):
    for key, value in parameters.items():
        if isinstance(value, dict):
            yield from flatten(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def test_config_file_sets_only_declared_parameters_with_valid_values():
    document = yaml.safe_load((REPO / "config" / "mrad.yaml").read_text())
    values = dict(flatten(document["/**"]["ros__parameters"]))
    declared = {**node_parameters(tf_available=True), **detector_parameters()}
    assert set(values) == set(declared)
    for name, value in values.items():
        validate(name, declared[name], value)
    for name, parameter in detector_parameters().items():
        assert values[name] == parameter.default, f"{name}: config and library defaults differ"
    for name in ("reference_scale", "shadows"):
        assert values[name] == declared[name].default, f"{name}: config and node defaults differ"


@pytest.mark.skipif(
    importlib.util.find_spec("launch_ros") is None, reason="launch_ros needs a ROS 2 distro"
)
def test_generate_launch_description_loads():
    spec = importlib.util.spec_from_file_location("detect_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    assert len(description.entities) >= 2
