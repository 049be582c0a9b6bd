"""A ROS user drops the repository into a colcon workspace and builds it."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
COLCON = Path(sys.executable).parent / "colcon"
NOT_SOURCES = shutil.ignore_patterns(
    ".venv",
    ".git",
    "data",
    "reports",
    "build",
    "install",
    "log",
    "__pycache__",
    ".pytest_cache",
    ".ruff_cache",
    ".hypothesis",
    "*.egg-info",
)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    if not COLCON.exists():
        pytest.skip("colcon is not installed in this environment")
    workspace = tmp_path_factory.mktemp("ws")
    shutil.copytree(REPO, workspace / "src" / "allo_mrad_ros", ignore=NOT_SOURCES)
    result = subprocess.run(
        [str(COLCON), "build", "--event-handlers", "console_direct-"],
        cwd=workspace,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return workspace / "install" / "allo_mrad_ros"


def installed_env(installed):
    site = next(installed.glob("lib/python3*/site-packages"))
    return {**os.environ, "AMENT_PREFIX_PATH": str(installed), "PYTHONPATH": str(site)}


def test_colcon_installs_executables_where_ros2_run_finds_them(installed):
    lib = installed / "lib" / "allo_mrad_ros"
    for name in ("mrad_detector", "allo-bag", "allo-synth", "mrad_demo"):
        assert (lib / name).is_file(), name
    entry_points = next(installed.glob("lib/python3*/site-packages/*.egg-info/entry_points.txt"))
    assert "mrad_detector = allo_mrad_ros.ros.node:main" in entry_points.read_text()
    run = subprocess.run(
        [str(lib / "mrad_demo"), "--help"],
        env=installed_env(installed),
        cwd=installed,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0 and "built-in example" in run.stdout, run.stderr


def test_colcon_installs_package_data_and_the_ament_index_marker(installed):
    share = installed / "share" / "allo_mrad_ros"
    for relative in (
        "package.xml",
        "launch/detect.launch.py",
        "config/mrad.yaml",
        "config/mrad.rviz",
        "config/fastdds_loopback.xml",
        "meshes/station.glb",
    ):
        assert (share / relative).is_file(), relative
    marker = installed / "share" / "ament_index" / "resource_index" / "packages" / "allo_mrad_ros"
    assert marker.is_file()


def test_installed_package_finds_its_share_directory_through_the_ament_index(installed):
    env = installed_env(installed)
    code = (
        "from allo_mrad_ros.resources import share_path; print(share_path('meshes', 'station.glb'))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        cwd=installed,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert (
        Path(out.stdout.strip()) == installed / "share" / "allo_mrad_ros" / "meshes" / "station.glb"
    )


def test_colcon_installs_no_benchmark_or_harness_and_no_psutil(installed):
    site = next(installed.glob("lib/python3*/site-packages"))
    top_level = {path.name for path in site.iterdir()}
    assert {"allo_mrad_ros", "rosbag_tools"} <= top_level
    assert not top_level & {"benchmarks", "harness", "test"}, sorted(top_level)
    assert not (site / "allo_mrad_ros" / "benchmarks").exists()
    # The robot needs no psutil: only the benchmarks and the tests read process figures.
    requires = next(site.glob("*.egg-info/requires.txt"), None)
    assert requires is None or "psutil" not in requires.read_text()
    manifest = (installed / "share" / "allo_mrad_ros" / "package.xml").read_text()
    assert "<exec_depend>python3-psutil</exec_depend>" not in manifest
