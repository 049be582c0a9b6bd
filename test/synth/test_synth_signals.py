"""`allo-synth` stopped by SIGTERM while it is still starting: exit status 130, one line,
no sequence and no hidden ``.out.partial-*`` left, as `allo-bag` (its entry point installs
the handlers before the heavy imports)."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from signal_probes import (
    assert_interrupted,
    catches_sigterm,
    held_at,
    loaded_numpy,
    start_command,
    wait_for,
)

TIME_LIMIT_S = 120.0
pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")


@pytest.mark.parametrize("delay_s", [0.0, 0.2])
def test_sigterm_while_importing_exits_130_and_leaves_nothing(tmp_path, delay_s):
    out = tmp_path / "out"
    out.mkdir()
    argv = ["generate", "--preset", "smoke", "--frames", "4", "--width", "160"]
    argv += ["--height", "90", "--out", str(out / "seq")]
    # Held after its first frame: still running at the signal however fast the machine is.
    held = held_at("generate-frame", tmp_path / "held")
    process = start_command(["allo_mrad_ros.synth.entry", *argv], tmp_path, held)
    try:
        wait_for(process, lambda: loaded_numpy(process.pid), "NumPy loaded", TIME_LIMIT_S)
        # NumPy comes with the command's own imports: by then the handler must be in place.
        assert catches_sigterm(process.pid)
        time.sleep(delay_s)
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=TIME_LIMIT_S)
    finally:
        if process.poll() is None:
            process.kill()
    assert_interrupted(process, stderr)
    assert sorted(p.name for p in out.iterdir()) == []
