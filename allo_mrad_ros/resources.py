"""Locate the package's installed data (meshes, config, launch files).

The same code runs from a colcon install (ament index), a pip install (``<prefix>/share``)
and a source checkout (editable install, tests), so the lookup tries them in that order.
"""

from __future__ import annotations

import re
import sys
from importlib import metadata
from pathlib import Path

from allo_mrad_ros.errors import InvalidInput

PACKAGE = "allo_mrad_ros"
_SOURCE_ROOT = Path(__file__).resolve().parent.parent


class ResourceError(InvalidInput, FileNotFoundError):
    """A data file of the package could not be found."""


def share_dir() -> Path:
    """Return the directory that holds ``meshes/``, ``config/`` and ``launch/``.

    Returns
    -------
    pathlib.Path
        The ament share directory when the package is installed in a ROS workspace, else
        ``<sys.prefix>/share/allo_mrad_ros`` for a pip install, else the source checkout.
    """
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )

        try:
            return Path(get_package_share_directory(PACKAGE))
        except (PackageNotFoundError, KeyError, ValueError, OSError):
            pass
    except ImportError:
        pass
    if (_SOURCE_ROOT / "package.xml").is_file():
        return _SOURCE_ROOT
    prefixed = Path(sys.prefix) / "share" / PACKAGE
    if prefixed.is_dir():
        return prefixed
    return _SOURCE_ROOT


def share_path(*parts: str) -> Path:
    """Return the path of an installed data file, raising if it does not exist.

    Parameters
    ----------
    *parts : str
        Path components below the share directory, e.g. ``("meshes", "station.glb")``.

    Returns
    -------
    pathlib.Path
        The existing file or directory.

    Raises
    ------
    ResourceError
        If the file is not installed.
    """
    path = share_dir().joinpath(*parts)
    if not path.exists():
        raise ResourceError(f"package data file not found: {path}")
    return path


def package_version() -> str:
    """Return the installed package's version (``allo-bag --version``, ``allo-synth --version``).

    Returns
    -------
    str
        The version in the package metadata (pip, colcon), else the ``<version>`` of the
        installed ``package.xml`` (the two are bumped together), else ``"unknown"``.
    """
    try:
        return metadata.version(PACKAGE)
    except metadata.PackageNotFoundError:
        pass
    try:
        text = share_path("package.xml").read_text(encoding="utf-8")
    except (ResourceError, OSError):
        return "unknown"
    found = re.search(r"<version>\s*([^<\s]+)\s*</version>", text)
    return found.group(1) if found else "unknown"
