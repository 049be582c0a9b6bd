"""The import rule of ARCHITECTURE.md, checked on the source: nothing imports upwards (the
layers are read from ARCHITECTURE.md's table), the detector core imports nothing else of the
package but the exception root, ROS stays at the edge, nothing installed imports the
benchmarks or the harness, and no modules import each other round a loop (an import inside a
function counts as much as one at module level)."""

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
    "benchmarks.transport",
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


# What the package root (allo_mrad_ros/__init__.py, run by every import of the package) may
# import: ``resources``, for ``__version__`` when it is asked for.
ROOT_MAY_IMPORT = {"resources"}


def violations(module: str, text: str, is_package: bool = False) -> list[str]:
    """Where ``module`` (source ``text``) breaks the import rule."""
    unit = _unit(module)
    found = []
    imported = _imports(module, text, is_package)
    if module == "allo_mrad_ros":
        return [
            f"the package root imports {name}"
            for name in sorted(imported)
            if _unit(name) is not None and _unit(name) not in ROOT_MAY_IMPORT
        ]
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


def test_the_package_root_imports_only_resources():
    assert not violations(
        "allo_mrad_ros", "def f():\n    from allo_mrad_ros.resources import v\n", True
    )
    assert violations("allo_mrad_ros", "from allo_mrad_ros.pipeline import Pipeline\n", True)


def test_the_ros_edge_admits_no_namesakes():
    ros = "import rclpy\n"
    assert not violations("benchmarks.node", ros)
    assert not violations("allo_mrad_ros.ros.inputs", ros)
    for namesake in ("benchmarks.node_extra", "allo_mrad_ros.demo_tools", "allo_mrad_ros.rosy"):
        assert violations(namesake, ros) == [f"{namesake} imports ROS package rclpy"]


def import_graph(sources: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """Module -> the modules of ``sources`` it imports.

    ``sources`` maps a module's name to its text and whether it is a package's
    ``__init__``. Every import statement counts, wherever it stands (module level, inside a
    function, under ``TYPE_CHECKING``). ``from p import n`` imports the module ``p.n`` where
    there is one, else the module ``p`` (a name it defines); ``import p.q.r`` the innermost of
    those that is a module of ``sources``.
    """
    graph = {}
    for module, (text, is_package) in sources.items():
        package = module if is_package else module.rpartition(".")[0]
        imported = set()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    name = alias.name
                    while name and name not in sources:
                        name = name.rpartition(".")[0]
                    imported.add(name)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")
                    anchor = parts[: len(parts) - node.level + 1]
                    base = ".".join([*anchor, *([node.module] if node.module else [])])
                for alias in node.names:
                    submodule = f"{base}.{alias.name}"
                    imported.add(submodule if submodule in sources else base)
        graph[module] = {name for name in imported if name in sources and name != module}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The modules that import each other, directly or round a loop: every strongly
    connected component of more than one module, sorted.

    Plain reachability (a module and everything that reaches it and that it reaches), not
    an efficient algorithm: the graph has a few hundred modules.
    """

    def reach(start: str) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            for name in graph[todo.pop()] - seen:
                seen.add(name)
                todo.append(name)
        return seen

    reached = {module: reach(module) for module in graph}
    cycles = set()
    for module in graph:
        component = {other for other in reached[module] if module in reached[other]}
        if len(component) > 1:
            cycles.add(tuple(sorted(component)))
    return [list(cycle) for cycle in sorted(cycles)]


def test_no_module_imports_itself_round_a_loop():
    sources = {
        _module_name(path): (path.read_text(encoding="utf-8"), path.name == "__init__.py")
        for path in _sources()
    }
    graph = import_graph(sources)
    loops = [
        f"{' <-> '.join(cycle)}: "
        + ", ".join(f"{a} -> {b}" for a in cycle for b in sorted(graph[a] & set(cycle)))
        for cycle in import_cycles(graph)
    ]
    assert loops == []


def test_the_cycle_check_finds_loops_module_level_or_deferred():
    # a -> b at module level, b -> c inside a function, c -> a by `import`: one loop of
    # three; d imports into it but is not on it, and e's two imports name a's package.
    sources = {
        "pkg": ("from pkg.a import run\n", True),
        "pkg.a": ("from pkg import b\n", False),
        "pkg.b": ("def later():\n    from .c import helper\n", False),
        "pkg.c": ("import pkg.a\nimport numpy\n", False),
        "pkg.d": ("from pkg.a import run\n", False),
        "pkg.e": ("from pkg import VERSION\nimport pkg.a.run\n", False),
    }
    graph = import_graph(sources)
    assert graph == {
        "pkg": {"pkg.a"},
        "pkg.a": {"pkg.b"},
        "pkg.b": {"pkg.c"},
        "pkg.c": {"pkg.a"},
        "pkg.d": {"pkg.a"},
        "pkg.e": {"pkg", "pkg.a"},
    }
    assert import_cycles(graph) == [["pkg.a", "pkg.b", "pkg.c"]]
    # Two loops through one module are one component; a chain without a loop is none.
    assert import_cycles({"x": {"y", "z"}, "y": {"x"}, "z": {"x"}}) == [["x", "y", "z"]]
    assert import_cycles({"x": {"y"}, "y": {"z"}, "z": set()}) == []
