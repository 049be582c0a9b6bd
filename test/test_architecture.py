"""The import rule of ARCHITECTURE.md, checked on the source: nothing imports upwards (the
layers are read from ARCHITECTURE.md's table), the detector core imports nothing else of the
package but the exception root, ROS stays at the edge, nothing installed imports the
benchmarks or the harness."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# What setup.py installs, and the top-level folders that are units of their own
# (rosbag_tools is installed, harness and benchmarks are not).
INSTALLED_TREES = ("allo_mrad_ros", "rosbag_tools")
TOP_LEVEL_UNITS = ("rosbag_tools", "harness", "benchmarks")


def _layers() -> dict[str, int]:
    """The layer table of ARCHITECTURE.md ("What may import what"): unit -> layer."""
    text = (REPO / "ARCHITECTURE.md").read_text(encoding="utf-8")
    section = text.split("## What may import what", 1)[1].split("\n## ", 1)[0]
    layers = {}
    for layer, units in re.findall(r"^\| (\d+) \|(.*)\|$", section, re.MULTILINE):
        for unit in re.findall(r"`(\w+)`", units):
            assert unit not in layers, f"ARCHITECTURE.md gives {unit} two layers"
            layers[unit] = int(layer)
    return layers


# Layers, lowest first; a unit imports only units of a lower layer (and itself).
LAYERS: dict[str, int] = _layers()
# What the detector core may import of the rest of the package: the exception root alone.
DETECTOR_MAY_IMPORT = {None, "detector", "errors"}
ROS_PACKAGES = {
    "rclpy",
    "sensor_msgs",
    "geometry_msgs",
    "std_msgs",
    "diagnostic_msgs",
    "visualization_msgs",
    "rcl_interfaces",
    "tf2_ros",
    "launch",
    "launch_ros",
}
# Where ROS may be imported, matched exactly (a package with everything under it, a module by
# its own name only): the node and its helpers, the live demo, the bag player, the test
# harness's camera feed and the node benchmarks.
ROS_EDGE_PACKAGES = ("allo_mrad_ros.ros",)
ROS_EDGE_MODULES = {
    "allo_mrad_ros.demo",
    "rosbag_tools.play",
    "harness.feed",
    "benchmarks.node",
    "benchmarks.node_session",
    "benchmarks.node_outputs",
    "benchmarks.node_profile",
    "benchmarks.flood",
}


def _at_ros_edge(module: str) -> bool:
    return module in ROS_EDGE_MODULES or any(
        module == package or module.startswith(f"{package}.") for package in ROS_EDGE_PACKAGES
    )


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(module: str, text: str, is_package: bool = False) -> set[str]:
    """Absolute names of every module ``text`` imports (relative imports resolved)."""
    package = module if is_package else module.rpartition(".")[0]
    names = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, *([node.module] if node.module else [])])
            names.add(base)
            # `from allo_mrad_ros import interface` imports the module allo_mrad_ros.interface.
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def _unit(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] in TOP_LEVEL_UNITS:
        return parts[0]
    if parts[0] == "allo_mrad_ros" and len(parts) > 1:
        return parts[1]
    return None


def _sources(trees: tuple[str, ...] = (*INSTALLED_TREES, *TOP_LEVEL_UNITS)) -> list[Path]:
    return sorted({path for tree in trees for path in REPO.glob(f"{tree}/**/*.py")})


def test_every_unit_has_a_layer():
    units = {_unit(_module_name(path)) for path in _sources()} - {None}
    assert units <= set(LAYERS), f"give these a layer in ARCHITECTURE.md: {units - set(LAYERS)}"
    assert set(TOP_LEVEL_UNITS) <= set(LAYERS)


def test_the_package_has_no_unit_named_after_a_top_level_folder():
    # `allo_mrad_ros/benchmarks` would take the layer of the top-level benchmarks/ and be
    # installed on the robot.
    package_units = {_unit(_module_name(path)) for path in _sources(("allo_mrad_ros",))}
    assert not package_units & set(TOP_LEVEL_UNITS)


def test_nothing_installed_sits_above_the_harness_and_the_benchmarks():
    installed = {_unit(_module_name(path)) for path in _sources(INSTALLED_TREES)} - {None}
    assert max(LAYERS[unit] for unit in installed) < LAYERS["harness"] < LAYERS["benchmarks"]


def violations(module: str, text: str, is_package: bool = False) -> list[str]:
    """Where ``module`` (source ``text``) breaks the import rule."""
    unit = _unit(module)
    found = []
    imported = _imports(module, text, is_package)
    for name in sorted(imported):
        other = _unit(name)
        upward = other in LAYERS and other != unit and LAYERS[other] >= LAYERS[unit]
        if upward:
            found.append(f"{module} (layer {LAYERS[unit]}) imports {name} ({LAYERS[other]})")
        if name.split(".")[0] in ROS_PACKAGES and not _at_ros_edge(module):
            found.append(f"{module} imports ROS package {name}")
        if unit == "detector" and other not in DETECTOR_MAY_IMPORT:
            found.append(f"the detector core ({module}) imports {name}")
    return found


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(REPO)))
def test_nothing_imports_upwards_and_ros_stays_at_the_edge(path):
    text = path.read_text(encoding="utf-8")
    assert violations(_module_name(path), text, path.name == "__init__.py") == []


def test_the_rule_catches_upward_ros_and_core_imports():
    upward = "from allo_mrad_ros.ros import node\nimport rclpy\n"
    assert len(violations("allo_mrad_ros.evaluation.probe", upward)) == 3
    assert violations("allo_mrad_ros.detector.probe", "from ..interface import MONO8\n")
    assert violations("allo_mrad_ros.detector.probe", "from allo_mrad_ros import options\n")
    # The exception root is the one exception: the detector's errors derive from it.
    assert not violations("allo_mrad_ros.detector.probe", "from ..errors import InvalidInput\n")
    assert violations("allo_mrad_ros.pipeline", "from rosbag_tools.bag_source import x\n")
    assert not violations("allo_mrad_ros.ros.probe", upward)
    # Installed code never imports what is not installed.
    assert violations("allo_mrad_ros.ros.probe", "from harness.feed import CameraFeed\n")
    assert violations("rosbag_tools.probe", "import benchmarks\n")
    assert violations("harness.probe", "from benchmarks.node import run\n")
    assert not violations("benchmarks.probe", "from harness.feed import CameraFeed\n")


def test_the_ros_edge_admits_no_namesakes():
    ros = "import rclpy\n"
    assert not violations("benchmarks.node", ros)
    assert not violations("allo_mrad_ros.ros.inputs", ros)
    for namesake in ("benchmarks.node_extra", "allo_mrad_ros.demo_tools", "allo_mrad_ros.rosy"):
        assert violations(namesake, ros) == [f"{namesake} imports ROS package rclpy"]
