"""ament_python build of allo_mrad_ros (also installable with pip)."""

from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "allo_mrad_ros"


def _files(pattern: str) -> list[str]:
    # setuptools wants paths relative to this file, as strings.
    return sorted(str(path) for path in Path().glob(pattern) if path.is_file())


setup(
    name=PACKAGE,
    version="0.2.0",
    # The node's package and the bag tools only: benchmarks/, harness/ and test/ stay in the
    # repository (colcon and pip install nothing of them on a robot).
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*", "rosbag_tools", "rosbag_tools.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", _files("launch/*.py")),
        (f"share/{PACKAGE}/config", _files("config/*")),
        (f"share/{PACKAGE}/meshes", _files("meshes/*")),
    ],
    package_data={PACKAGE: ["data/*"]},
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="allo_mrad_ros maintainers",
    maintainer_email="maintainers@allo-mrad-ros.invalid",
    description="Model-reference anomaly detection (MRAD) for space-station proximity operations.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "mrad_demo = allo_mrad_ros.demo:main",
            "mrad_detector = allo_mrad_ros.ros.node:main",
            "mrad_detector_lifecycle = allo_mrad_ros.ros.lifecycle:main",
            "allo-synth = allo_mrad_ros.synth.entry:main",
            "allo-bag = rosbag_tools.entry:main",
        ],
    },
)
