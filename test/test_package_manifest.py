"""package.xml names only real ROS packages and rosdep keys, and covers every import.

The allowed names live in ``test/data/rosdep_keys.txt``, copied from rosdistro (the file
says which commit); ``rosdep install`` fails on the first unknown key, so one typo breaks the
distro route for every user.
"""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KEYS_FILE = ROOT / "test" / "data" / "rosdep_keys.txt"
RUNTIME_TREES = ("allo_mrad_ros", "rosbag_tools", "launch")
# Trees that run only in development (tests, benchmarks and what they share): not installed.
DEV_TREES = ("test", "harness", "benchmarks")
# The packages and the development trees, plus the tests' own helper modules (test/**/*.py
# that are not tests).
FIRST_PARTY = {"allo_mrad_ros", "rosbag_tools", "harness", "benchmarks"} | {
    path.stem for path in (ROOT / "test").rglob("*.py") if not path.stem.startswith("test_")
}

# Import name -> the package.xml key that provides it on a distro, or the requirement name in
# requirements-distro*.txt (the pip part of the distro route) for modules rosdep has no key for.
MODULE_PROVIDERS = {
    "OpenGL": "python3-opengl",
    "PIL": "python3-pil",
    "cv2": "python3-opencv",
    "matplotlib": "python3-matplotlib",
    "numpy": "python3-numpy",
    "psutil": "python3-psutil",
    "scipy": "python3-scipy",
    "tqdm": "python3-tqdm",
    "yaml": "python3-yaml",
    "trimesh": "python3-trimesh-pip",
    "rosbags": "python3-rosbags-pip",
    "pyrender": "pyrender-maintained",
    "skyfield": "skyfield",
    "skyfield_data": "skyfield-data",
    "pytest": "python3-pytest",
    "pytest_timeout": "python3-pytest-timeout",
    "hypothesis": "python3-hypothesis",
    "sklearn": "python3-sklearn",
    "skimage": "python3-skimage",
    # Test-only oracles without a rosdep key: the pip world's requirements-dev.txt.
    "mcap": "mcap",
    "mcap_ros2": "mcap-ros2-support",
    "spectral": "spectral",
}

# ROS Python modules whose package is named otherwise: the tf2_ros module comes from
# tf2_ros_py (tf2_ros is the C++ package and does not pull it in).
ROS_MODULE_PACKAGES = {"tf2_ros": "tf2_ros_py"}

# Modules of optional extras, which neither the node nor `make test` needs: import name ->
# the requirements file that installs them, and the only modules allowed to import them.
OPTIONAL_PROVIDERS = {
    **{
        name: ("requirements-cycles.txt", "bpy", ("allo_mrad_ros/synth/cycles",))
        for name in ("bpy", "bmesh", "mathutils", "bpy_extras")
    },
    # The detector's PyTorch array backend: imported only when selected.
    "torch": (
        "requirements-torch.txt",
        "torch",
        ("allo_mrad_ros/detector/backends", "allo_mrad_ros/detector/torch_backend"),
    ),
}


def _allowed_names() -> dict[str, set[str]]:
    sections: dict[str, set[str]] = {}
    current = None
    for line in KEYS_FILE.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            current = sections.setdefault(line.strip("[]"), set())
        else:
            assert current is not None, f"{KEYS_FILE}: name before a [section]: {line}"
            current.add(line)
    return sections


def _manifest_depends() -> dict[str, set[str]]:
    root = ET.parse(ROOT / "package.xml").getroot()
    depends: dict[str, set[str]] = {}
    for element in root:
        if isinstance(element.tag, str) and element.tag.endswith("depend"):
            depends.setdefault(element.tag, set()).add(element.text.strip())
    return depends


def _requirement_names(path: Path) -> set[str]:
    """Requirement names of a pip requirements file and the files it includes (``-r``)."""
    names = set()
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line.startswith("-r "):
            names |= _requirement_names(path.parent / line[3:].strip())
        elif line and not line.startswith("-"):
            names.add(re.split(r"[<>=!~;\[ +]", line, maxsplit=1)[0].lower())
    return names


def _third_party_imports(trees: tuple[str, ...]) -> dict[str, str]:
    """Top-level third-party module -> one file importing it."""
    found: dict[str, str] = {}
    for tree in trees:
        for path in sorted((ROOT / tree).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top in sys.stdlib_module_names or top in FIRST_PARTY or top == "__future__":
                        continue
                    found.setdefault(top, str(path.relative_to(ROOT)))
    return found


def test_every_manifest_dependency_is_a_ros_package_or_a_rosdep_key():
    allowed = _allowed_names()
    valid = allowed["ros_packages"] | allowed["rosdep_keys"]
    for tag, names in _manifest_depends().items():
        unknown = sorted(names - valid)
        assert not unknown, f"package.xml <{tag}> names unknown rosdep keys: {unknown}"


def test_the_keys_that_broke_the_distro_route_stay_out():
    names = set().union(*_manifest_depends().values())
    # libosmesa6 and python3-skyfield are not rosdep keys; python3-pyrender-pip installs the
    # abandoned pyrender 0.1.45 over the import name of pyrender-maintained.
    assert not names & {"libosmesa6", "python3-skyfield", "python3-pyrender-pip"}


def test_every_runtime_import_has_a_provider_on_a_distro():
    depends = _manifest_depends()
    exec_keys = depends.get("exec_depend", set()) | depends.get("depend", set())
    distro_pip = _requirement_names(ROOT / "requirements-distro.txt") | _requirement_names(
        ROOT / "requirements-distro-nodeps.txt"
    )
    ros_packages = _allowed_names()["ros_packages"]
    missing = []
    for module, where in sorted(_third_party_imports(RUNTIME_TREES).items()):
        if module in ROS_MODULE_PACKAGES:
            package = ROS_MODULE_PACKAGES[module]
            if package not in exec_keys or package not in ros_packages:
                missing.append(f"{module} ({where}): add <exec_depend>{package}</exec_depend>")
            continue
        if module in ros_packages:
            if module not in exec_keys:
                missing.append(f"{module} ({where}): add <exec_depend>{module}</exec_depend>")
            continue
        if module in OPTIONAL_PROVIDERS:
            requirements, package, owners = OPTIONAL_PROVIDERS[module]
            if package not in _requirement_names(ROOT / requirements):
                missing.append(f"{module} ({where}): {package} is not in {requirements}")
            if not where.startswith(owners):
                missing.append(f"{module} ({where}): optional, import it only in {owners}")
            continue
        provider = MODULE_PROVIDERS.get(module)
        if provider is None:
            missing.append(f"{module} ({where}): no provider known; add it to MODULE_PROVIDERS")
        elif provider not in exec_keys and provider.lower() not in distro_pip:
            missing.append(
                f"{module} ({where}): {provider} is in neither package.xml nor "
                "requirements-distro*.txt"
            )
    assert not missing, "\n".join(missing)


def test_every_test_import_has_a_provider():
    depends = _manifest_depends()
    keys = set().union(*depends.values())
    dev = _requirement_names(ROOT / "requirements-dev.txt") | _requirement_names(
        ROOT / "requirements.txt"
    )
    missing = []
    for module, where in sorted(_third_party_imports(DEV_TREES).items()):
        provider = MODULE_PROVIDERS.get(module, ROS_MODULE_PACKAGES.get(module, module))
        if provider not in keys and provider.lower() not in dev and module not in keys:
            missing.append(f"{module} ({where})")
    assert not missing, f"test or benchmark imports without a key or requirement: {missing}"


# Markers that a pytest plugin defines (the suite runs with --strict-markers, so without the
# plugin a module using one fails at collection): marker -> the plugin's module.
PLUGIN_MARKERS = {"timeout": "pytest_timeout"}
_IMPORT_ERRORS = {"ImportError", "ModuleNotFoundError"}


def _catches_import_errors(handler: ast.ExceptHandler) -> bool:
    kinds = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
    return any(isinstance(kind, ast.Name) and kind.id in _IMPORT_ERRORS for kind in kinds)


def _dev_imports(tree: ast.AST) -> list[tuple[str, int, str]]:
    """(module, line, how) of each import in ``tree``: how is "import", "guarded" (inside a
    ``try`` that catches ImportError), "skip" (``pytest.importorskip`` with a reason),
    "skip without reason", or "marker" (a plugin's ``pytest.mark.<name>``)."""
    found: list[tuple[str, int, str]] = []

    def visit(node: ast.AST, guarded: bool) -> None:
        if isinstance(node, ast.Try) and any(map(_catches_import_errors, node.handlers)):
            for child in node.body:
                visit(child, True)
            for child in [*node.handlers, *node.orelse, *node.finalbody]:
                visit(child, guarded)
            return
        how = "guarded" if guarded else "import"
        if isinstance(node, ast.Import):
            found.extend((alias.name, node.lineno, how) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.module, node.lineno, how))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "importorskip"
            and node.args
            and isinstance(node.args[0], ast.Constant)
        ):
            reason = any(keyword.arg == "reason" for keyword in node.keywords)
            found.append(
                (node.args[0].value, node.lineno, "skip" if reason else "skip without reason")
            )
        elif (
            isinstance(node, ast.Attribute)
            and node.attr in PLUGIN_MARKERS
            and isinstance(node.value, ast.Attribute)
            and node.value.attr == "mark"
        ):
            found.append((PLUGIN_MARKERS[node.attr], node.lineno, "marker"))
        for child in ast.iter_child_nodes(node):
            visit(child, guarded)

    visit(tree, False)
    return found


def test_every_test_import_is_declared_or_skipped_with_a_reason():
    # `colcon test` on a distro has what package.xml declares (test_depend included) and the
    # venv of requirements-distro*.txt (docs/distro.md), nothing of requirements-dev.txt:
    # any other module must be imported where a missing one skips, with the reason, or is
    # caught; a module failing at collection takes every test of the run down.
    depends = _manifest_depends()
    keys = set().union(*depends.values())
    distro_pip = _requirement_names(ROOT / "requirements-distro.txt") | _requirement_names(
        ROOT / "requirements-distro-nodeps.txt"
    )
    missing = []
    for tree in DEV_TREES:
        for path in sorted((ROOT / tree).rglob("*.py")):
            where = path.relative_to(ROOT)
            for name, line, how in _dev_imports(ast.parse(path.read_text(), str(path))):
                module = name.split(".")[0]
                if module in sys.stdlib_module_names or module in FIRST_PARTY:
                    continue
                if module == "__future__" or how in ("guarded", "skip"):
                    continue
                provider = MODULE_PROVIDERS.get(module, ROS_MODULE_PACKAGES.get(module, module))
                if provider in keys or provider.lower() in distro_pip:
                    continue
                missing.append(f"{where}:{line}: {name} ({how})")
    assert not missing, (
        "imports that neither package.xml nor requirements-distro*.txt provide; declare a "
        "test_depend key, or use pytest.importorskip(name, reason=...):\n" + "\n".join(missing)
    )


@pytest.mark.parametrize("name", ["requirements-distro.txt", "requirements-distro-nodeps.txt"])
def test_distro_requirements_use_ranges_and_no_ros_wheels(name):
    for number, raw in enumerate((ROOT / name).read_text().splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        assert "==" not in line, f"{name}:{number}: pin {line!r}; the distro route uses ranges"
        assert not line.lower().startswith("ros-"), f"{name}:{number}: ROS wheel {line!r}"
    if name == "requirements-distro.txt":
        assert re.search(r"^numpy[^#\n]*<2", (ROOT / name).read_text(), re.MULTILINE), (
            "NumPy must stay below 2 on a distro: its message packages are built against 1.x"
        )


def test_every_message_package_the_bags_carry_is_declared():
    # allo-bag play imports each topic's message type by name (no import statement to check):
    # /tf and /tf_static need tf2_msgs on the robot.
    from rosbag_tools import topics

    exec_keys = _manifest_depends().get("exec_depend", set())
    packages = {
        value.split("/")[0]
        for value in vars(topics).values()
        if isinstance(value, str) and re.fullmatch(r"\w+/msg/\w+", value)
    }
    assert "tf2_msgs" in packages
    assert sorted(packages - exec_keys) == []


def test_imported_ros_modules_are_declared_and_viewing_stays_optional():
    exec_keys = _manifest_depends().get("exec_depend", set())
    # The node imports tf2_ros (from tf2_ros_py) and vision_msgs where installed.
    assert {"tf2_ros_py", "vision_msgs"} <= exec_keys
    # rosdep must not put RViz on a headless robot computer.
    assert "rviz2" not in set().union(*_manifest_depends().values())
