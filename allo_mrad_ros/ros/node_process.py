"""The node as a separate process, as ``make demo`` (and the tests and benchmarks) run it.

:func:`start_node` starts ``mrad_detector`` with ``name:=value`` parameters in its own
process, so a peer in this process (the demo's recorder, a test's camera feed) talks to it
over DDS as a camera driver and a viewer would. Keep DDS on loopback
(``config/fastdds_loopback.xml``) when using it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


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
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
