"""The reduced bad-input sweep (``make sweep`` runs all of it): every quick case is clean.

It runs as its own process, as ``make sweep`` does, and fails with the table of the cases
that are not clean (a traceback, a crash, a partial output, a silent wrong result or an
unclear error), so a regression of any entry point shows up here.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from sweep_verdicts import CLEAN, UNCLEAR, classify_exit, error_lines

from harness.dds import current_domain, domain_apart

SWEEP = Path(__file__).resolve().parent / "sweep.py"


@pytest.mark.ros
@pytest.mark.slow
def test_quick_sweep_is_all_clean(tmp_path):
    pytest.importorskip("rclpy")  # the node's cases need it (absent from make test-distro)
    # A DDS domain of its own: a node left by another test must not answer for the sweep's.
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain_apart(current_domain(), 17))}
    done = subprocess.run(
        [sys.executable, str(SWEEP), "--quick", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=900,
        env=env,
    )
    print(done.stdout[-6000:])
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-3000:]
    assert (tmp_path / "sweep.json").is_file() and (tmp_path / "sweep.md").is_file()


def test_verdicts_can_fail():
    # The classification itself: each failure is named, never passed as clean.
    assert classify_exit(1, "x: error: bad thing\n", "bad", [], True)[0] == CLEAN
    assert classify_exit(0, "", "bad", [], True)[0] == "silent wrong"
    assert (
        classify_exit(1, "Traceback (most recent call last):\n  x\nE: y\n", "", [], True)[0]
        == "traceback"
    )
    assert classify_exit(None, "", "", [], True)[0] == "crash"
    assert classify_exit(-9, "", "", [], True)[0] == "crash"
    assert classify_exit(1, "e: one\ne: two\n", "", [], True)[0] == UNCLEAR
    assert classify_exit(1, "e: other\n", "bad", [], True)[0] == UNCLEAR
    assert (
        classify_exit(1, "x: error: bad\n", "bad", [".out.partial-1"], True)[0] == "partial output"
    )
    assert classify_exit(0, "", "", [], False, "metrics differ")[0] == "silent wrong"
    usage = "usage: prog [-h]\n       prog more\nprog: error: argument --x: bad\n"
    assert error_lines(usage) == ["prog: error: argument --x: bad"]
