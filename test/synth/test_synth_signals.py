"""`allo-synth` stopped by SIGTERM while it is still starting: exit status 130, one line,
no sequence and no hidden ``.out.partial-*`` left, as `allo-bag` (its entry point installs
the handlers before the heavy imports)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from signal_probes import catches_sigterm, default_signals, loaded_numpy

TIME_LIMIT_S = 120.0
pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")


@pytest.mark.parametrize("delay_s", [0.0, 0.2])
def test_sigterm_while_importing_exits_130_and_leaves_nothing(tmp_path, delay_s):
    out = tmp_path / "out"
    out.mkdir()
    argv = ["generate", "--preset", "smoke", "--frames", "4", "--width", "160"]
    argv += ["--height", "90", "--out", str(out / "seq")]
    process = subprocess.Popen(
        [sys.executable, "-m", "allo_mrad_ros.synth.entry", *argv],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_signals,
    )
    try:
        start = time.monotonic()
        while not loaded_numpy(process.pid):
            assert process.poll() is None, "allo-synth ended before NumPy was loaded"
            assert time.monotonic() - start < TIME_LIMIT_S, "NumPy never loaded"
            time.sleep(0.001)
        # NumPy comes with the command's own imports: by then the handler must be in place.
        assert catches_sigterm(process.pid)
        time.sleep(delay_s)
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=TIME_LIMIT_S)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1].endswith("interrupted"), stderr
    assert "Traceback" not in stderr
    assert sorted(p.name for p in out.iterdir()) == []
