"""`allo-synth import-allo --copy` stopped by SIGTERM at any point: while it starts, while it
copies (held after its first frame, so the signal lands there on any machine) and once the
sequence is in place: exit status 130 and one line, never killed by the signal; nothing but
a complete sequence is left."""

from __future__ import annotations

import signal
from pathlib import Path

import cv2
import numpy as np
import pytest
from signal_probes import (
    catches_sigterm,
    held_at,
    loaded_numpy,
    start_command,
    wait_for,
)

TIME_LIMIT_S = 120.0
pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")


@pytest.fixture(scope="module")
def split(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("allo") / "ALLO" / "test"
    folder = root / "Camera0"
    (folder / "images").mkdir(parents=True)
    (folder / "masks").mkdir()
    for index, name in enumerate(["1_normal_1.png", "2_normal_10.png", "3_normal_5.png"]):
        cv2.imwrite(str(folder / "images" / name), np.full((1080, 1920, 3), 30 * index, np.uint8))
        cv2.imwrite(str(folder / "masks" / name), np.ones((1080, 1920), np.uint8))
    return root


@pytest.mark.parametrize("point", ["handler", "numpy", "copying", "done"])
def test_sigterm_at_any_point_of_the_import_exits_130(split, tmp_path, point):
    out = tmp_path / "out"
    out.mkdir()
    marker = tmp_path / "held"
    hold = "command-done" if point == "done" else "import-frame"
    argv = ["allo_mrad_ros.synth.entry", "import-allo", str(split), "--copy", "--quiet"]
    argv += ["--out", str(out / "seq")]
    process = start_command(argv, tmp_path, held_at(hold, marker))
    try:
        ready = {
            "handler": lambda: catches_sigterm(process.pid),
            "numpy": lambda: loaded_numpy(process.pid),
        }.get(point, marker.exists)
        wait_for(process, ready, point, TIME_LIMIT_S)
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=TIME_LIMIT_S)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "interrupted" in lines[0], stderr
    left = sorted(p.name for p in out.iterdir())
    if point == "done":
        assert left == ["seq"] and (out / "seq" / "frames.csv").is_file()
    else:
        assert left == []
