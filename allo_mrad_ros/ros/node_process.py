"""The node as a separate process, as ``make demo`` (and the tests and benchmarks) run it.

:func:`start_node` starts ``mrad_detector`` with ``name:=value`` parameters in its own
process, so a peer in this process (the demo's recorder, a test's camera feed) talks to it
over DDS as a camera driver and a viewer would. Keep DDS on loopback
(``config/fastdds_loopback.xml``, :func:`use_loopback_profile`) when using it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import MutableMapping
from importlib import metadata
from pathlib import Path

from allo_mrad_ros.resources import share_path

# The variable naming Fast DDS's XML profile, by Fast DDS major version: 3 (ROS 2 Kilted on)
# reads the first and warns when the second is set; 2 (Humble's 2.6, Jazzy's 2.14) reads only
# the second, so a profile given under the new name is silently not applied there.
PROFILE_VARIABLES = {3: "FASTDDS_DEFAULT_PROFILES_FILE", 2: "FASTRTPS_DEFAULT_PROFILES_FILE"}
# Distributions whose Fast DDS is version 2.
_FAST_DDS_2_DISTROS = frozenset({"humble", "iron", "jazzy"})


def fast_dds_major() -> int:
    """Return the major version of the Fast DDS that rclpy loads here (2 or 3).

    The pip wheels name it (``ros-fastdds`` 3.x, ``ros-fastrtps`` 2.x); without them the
    sourced distribution does (``ROS_DISTRO``); else 3.
    """
    for distribution, major in (("ros-fastdds", 3), ("ros-fastrtps", 2)):
        try:
            metadata.version(distribution)
        except metadata.PackageNotFoundError:
            continue
        return major
    return 2 if os.environ.get("ROS_DISTRO", "") in _FAST_DDS_2_DISTROS else 3


def use_loopback_profile(
    environ: MutableMapping[str, str] | None = None,
    profile: Path | None = None,
    major: int | None = None,
) -> str:
    """Point this Fast DDS at the loopback profile, unless a profile is chosen already.

    The profile is the one given under either name (``make`` exports the new one), else
    ``profile``, else the installed ``config/fastdds_loopback.xml``; it is set under the
    name this Fast DDS reads (:data:`PROFILE_VARIABLES`) and left under the other.

    Parameters
    ----------
    environ : mutable mapping, optional
        The environment to change (default ``os.environ``: this process and its children).
    profile : pathlib.Path, optional
        The profile to use when none is set.
    major : int, optional
        Fast DDS's major version (default :func:`fast_dds_major`).

    Returns
    -------
    str
        The variable that names the profile for this Fast DDS.
    """
    environ = os.environ if environ is None else environ
    variable = PROFILE_VARIABLES[fast_dds_major() if major is None else major]
    if not environ.get(variable):
        given = [environ[name] for name in PROFILE_VARIABLES.values() if environ.get(name)]
        chosen = given[0] if given else str(profile or share_path("config", "fastdds_loopback.xml"))
        environ[variable] = chosen
    return variable


def start_node(log_path: Path, *parameters: str, namespace: str = "") -> subprocess.Popen:
    """Start the node as a separate process with ``name:=value`` parameters.

    ``pose_source:=topic`` comes first (it can be overridden); output goes to ``log_path``.
    """
    arguments = [sys.executable, "-m", "allo_mrad_ros.ros.node", "--ros-args"]
    if namespace:
        arguments += ["-r", f"__ns:=/{namespace.strip('/')}"]
    for parameter in ("pose_source:=topic", *parameters):
        arguments += ["-p", parameter]
    log = log_path.open("w")
    return subprocess.Popen(arguments, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ))


def stop_node(process: subprocess.Popen) -> None:
    """Terminate the node process (kill it if it does not stop within 10 s)."""
    process.terminate()
    wait_or_kill(process, 10)


def wait_or_kill(process: subprocess.Popen, timeout_s: float) -> bool:
    """Wait up to ``timeout_s`` for ``process`` to end, else kill it and reap it.

    Returns
    -------
    bool
        True if it ended within the time, False if it had to be killed.
    """
    try:
        process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        return False
    return True
