"""The import rule of ARCHITECTURE.md, checked on the source: nothing imports upwards, the
detector core imports nothing else of the package but the exception root, ROS stays at the
edge."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# Layers, lowest first; a unit imports only units of a lower layer (and itself).
LAYERS: dict[str, int] = {
    "errors": 0,
    "interface": 0,
    "options": 0,
    "staging": 1,
    "targets": 1,
    "camera": 1,
    "geometry": 1,
    "resources": 1,
    "detector": 2,
    "metrics": 2,
    "localisation": 3,
    "render": 2,
    "sequence": 2,
    "visualise": 2,
    "example_scene": 2,
    "sky": 3,
    "allo_format": 3,
    "view": 4,
    "ephemeris": 4,
    "pipeline": 5,
    "allo_ephemeris": 5,
    "evaluation": 6,
    "allo_import": 6,
    "ros": 7,
    "synth": 7,
    "rosbag_tools": 8,
    "benchmarks": 8,
    "demo": 8,
}
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
# Where ROS may be imported: the node and its helpers, the live demo, the node benchmark and
# profiler, and the bag player.
ROS_EDGE = (
    "allo_mrad_ros.ros",
    "allo_mrad_ros.demo",
    "allo_mrad_ros.benchmarks.node",
    "allo_mrad_ros.benchmarks.node_profile",
    "allo_mrad_ros.benchmarks.flood",
    "rosbag_tools.play",
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
    if parts[0] == "rosbag_tools":
        return "rosbag_tools"
    if parts[0] == "allo_mrad_ros" and len(parts) > 1:
        return parts[1]
    return None


def _sources() -> list[Path]:
    return sorted([*REPO.glob("allo_mrad_ros/**/*.py"), *REPO.glob("rosbag_tools/**/*.py")])


def test_every_unit_has_a_layer():
    units = {_unit(_module_name(path)) for path in _sources()} - {None}
    assert units <= set(LAYERS), f"give these a layer in ARCHITECTURE.md: {units - set(LAYERS)}"


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
        if name.split(".")[0] in ROS_PACKAGES and not module.startswith(ROS_EDGE):
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
