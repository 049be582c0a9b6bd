"""allo_mrad_ros: model-reference anomaly detection for space-station proximity operations.

The detector core (:mod:`allo_mrad_ros.detector`) is pure NumPy/OpenCV and knows nothing of
ROS; ROS lives at the edges (the node, the bag tools).
"""


def __getattr__(name: str) -> str:
    """``__version__``, read when asked: the installed metadata, else package.xml's (a source
    tree), as ``allo-bag --version`` prints it; importing the package reads nothing."""
    if name == "__version__":
        from allo_mrad_ros.resources import package_version

        return package_version()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
