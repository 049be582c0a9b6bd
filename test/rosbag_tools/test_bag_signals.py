"""`allo-bag write` stopped by SIGTERM at any point after its start: exit status 130, one
line, no bag and no hidden ``.bag.partial-*`` left.

The command runs as ``python -m rosbag_tools``, as the sweep runs it: that is the path on
which CPython ends a process by SIGINT (status -2) once a ``KeyboardInterrupt`` has left code
run by ``exec`` of a string, even a caught one.

The write is held after its first frame (``ALLO_HOLD_AT=bag-frame``), so on any machine it is
still running when the signal is sent: the test controls its timing, not the machine's speed.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
import pytest
from signal_probes import (
    assert_interrupted,
    catches_sigterm,
    held_at,
    loaded_numpy,
    start_command,
    wait_for,
)

from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.sequence import SequenceMeta, SequenceWriter

# Where the signal is sent: seconds after the handler is installed (the first line of the
# entry point), after NumPy is loaded (the command-line module is importing the detector),
# or after the hidden partial bag appears (the bag is being written).
POINTS = [("handler", 0.0), ("handler", 0.3), ("handler", 1.0), ("numpy", 0.0), ("numpy", 0.2),
          ("partial", 0.0), ("partial", 0.05), ("partial", 0.3)]  # fmt: skip
TIME_LIMIT_S = 120.0


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    """Noise frames at 640x360: a write of a few seconds, for a signal to land in."""
    root = tmp_path_factory.mktemp("seq") / "seq"
    camera = ALLO_INTRINSICS.scaled(1.0 / 3.0)
    rng = np.random.default_rng(0)
    with SequenceWriter(root, SequenceMeta(name="long", camera=camera, rate_hz=10.0)) as writer:
        for _ in range(24):
            writer.add_frame(
                split="test",
                camera=0,
                image=rng.integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8),
                mask=np.ones((camera.height, camera.width), np.uint8),
                position=[-30.0, -12.0, 6.0],
                quaternion=[0.0, 0.0, 0.0, 1.0],
                sun_direction=[0.6, 0.0, 0.8],
            )
    return root


def _wait(process, ready, what: str) -> None:
    wait_for(process, ready, what, TIME_LIMIT_S)


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
@pytest.mark.parametrize(("after", "delay_s"), POINTS)
def test_sigterm_at_any_point_exits_130_and_leaves_nothing(sequence, tmp_path, after, delay_s):
    out = tmp_path / "out"
    out.mkdir()
    argv = ["rosbag_tools", "write", str(sequence), str(out / "bag")]
    process = start_command(argv, tmp_path, held_at("bag-frame", tmp_path / "held"))
    try:
        if after == "handler":
            _wait(process, lambda: catches_sigterm(process.pid), "its SIGTERM handler")
        elif after == "numpy":
            _wait(process, lambda: loaded_numpy(process.pid), "NumPy loaded")
        else:
            _wait(
                process,
                lambda: any(".partial-" in p.name for p in out.iterdir()),
                "the partial bag",
            )
        time.sleep(delay_s)
        assert process.poll() is None, "the write ended before the signal"
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=TIME_LIMIT_S)
    finally:
        if process.poll() is None:
            process.kill()
    assert_interrupted(process, stderr)
    assert _leftovers(out) == []


INTERRUPT_IN_EXEC = """
import sys

import rosbags.serde.cdr as cdr
import rosbags.serde.utils as utils

compile_lines = utils.compile_lines


def interrupted_while_compiling(lines):
    # The signal lands while rosbags compiles a serialiser, so the interrupt is raised
    # inside the code that exec() runs.
    return compile_lines(["import os, signal", "os.kill(os.getpid(), signal.SIGTERM)", *lines])


utils.compile_lines = cdr.compile_lines = interrupted_while_compiling
from rosbag_tools.entry import main

sys.exit(main())
"""


def test_sigterm_raised_inside_exec_code_still_exits_130(sequence, tmp_path):
    """The window of the intermittent -2, made certain: the interrupt leaves rosbags'
    exec-compiled serialiser code while the bag is written."""
    (tmp_path / "interrupt_in_exec.py").write_text(INTERRUPT_IN_EXEC)
    out = tmp_path / "out"
    out.mkdir()
    argv = ["interrupt_in_exec", "write", str(sequence), str(out / "bag")]
    process = start_command(argv, tmp_path)
    _, stderr = process.communicate(timeout=TIME_LIMIT_S)
    assert process.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1] == "allo-bag write: interrupted", stderr
    assert _leftovers(out) == []


def test_sigterm_once_the_bag_is_in_place_exits_130(sequence, tmp_path):
    """The command has written the bag and not yet returned: still 130 and one line."""
    out = tmp_path / "out"
    out.mkdir()
    marker = tmp_path / "held"
    argv = ["rosbag_tools", "write", str(sequence), str(out / "bag")]
    process = start_command(argv, tmp_path, held_at("command-done", marker))
    try:
        _wait(process, marker.exists, "the end of the command")
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=TIME_LIMIT_S)
    finally:
        if process.poll() is None:
            process.kill()
    assert_interrupted(process, stderr)
    assert _leftovers(out) == ["bag"] and (out / "bag" / "metadata.yaml").is_file()


SIGNAL_AT_EXIT = """
import atexit
import sys
import time
from pathlib import Path


def held_at_exit():
    # Runs while the interpreter exits, after main() has returned its status.
    Path(sys.argv.pop()).touch()
    time.sleep(1.0)


atexit.register(held_at_exit)
from rosbag_tools.entry import main

sys.exit(main(sys.argv[1:-1]))
"""


def test_sigterm_while_the_interpreter_exits_never_ends_it_by_the_signal(sequence, tmp_path):
    """A signal after the command has returned (the bag written, the status given) cannot
    end the process by SIGTERM's default action (status -15): it exits with its status."""
    (tmp_path / "signal_at_exit.py").write_text(SIGNAL_AT_EXIT)
    out = tmp_path / "out"
    out.mkdir()
    marker = tmp_path / "exiting"
    argv = ["signal_at_exit", "write", str(sequence), str(out / "bag"), str(marker)]
    process = start_command(argv, tmp_path)
    try:
        _wait(process, marker.exists, "the interpreter's exit")
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=TIME_LIMIT_S)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, stderr
    assert _leftovers(out) == ["bag"]
