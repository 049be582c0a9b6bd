"""The final swap of a staged output: at every instant the path holds the old output or the
new one, whatever signal arrives; an old output that cannot be removed is reported, not
passed off as a failure; an old output a killed process left aside is put back.

Signals land through :data:`staging.between_swap_steps`, called between the two steps of
the swap, so they arrive exactly there on any machine."""

from __future__ import annotations

import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from allo_mrad_ros import staging
from allo_mrad_ros.staging import old_path, signals_as_interrupt, staged_folder
from allo_mrad_ros.targets import SEQUENCE, TargetError, check_target

REPO = Path(__file__).resolve().parents[1]


def _write(folder: Path, name: str) -> None:
    """A stand-in sequence named ``name``: the rule recognises it, the test tells which."""
    (folder / "sequence.yaml").write_text(f"format: allo-sequence/1\nname: {name}\n")
    (folder / "frames.csv").write_text("image,mask,reference\n")


def _old_output(out: Path) -> Path:
    out.mkdir()
    _write(out, "old")
    return out


def _replace(out: Path) -> None:
    with staged_folder(out) as folder:
        _write(folder, "new")


def _name(folder: Path) -> str:
    return (folder / "sequence.yaml").read_text().split("name: ")[1].strip()


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture(params=["exchange", "two renames"])
def swap(request, monkeypatch) -> str:
    """Both ways of swapping: the atomic exchange where the kernel has it (checked), and
    the two renames used where it has not."""
    if request.param == "two renames":
        monkeypatch.setattr(staging, "_renameat2", None)
    elif staging._renameat2 is None:
        pytest.skip("no renameat2 in this C library")
    return request.param


def test_the_path_is_never_empty_where_the_kernel_exchanges(tmp_path, monkeypatch):
    out = _old_output(tmp_path / "out")
    seen = []
    monkeypatch.setattr(staging, "between_swap_steps", lambda path: seen.append(path.exists()))
    _replace(out)
    assert seen == [staging._renameat2 is not None]
    assert _name(out) == "new" and _hidden(tmp_path) == []


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
@pytest.mark.parametrize("sender", ["main thread", "another thread"])
def test_a_signal_between_the_two_steps_leaves_the_new_output(
    tmp_path, monkeypatch, swap, signum, sender
):
    out = _old_output(tmp_path / "out")

    def signal_here(path: Path) -> None:
        if sender == "main thread":
            os.kill(os.getpid(), signum)
        else:
            thread = threading.Thread(target=os.kill, args=(os.getpid(), signum))
            thread.start()
            thread.join()

    monkeypatch.setattr(staging, "between_swap_steps", signal_here)
    with signals_as_interrupt():
        _replace(out)  # the interrupt came too late to stop anything: no Interrupted
    assert _name(out) == "new" and _hidden(tmp_path) == []


def test_a_held_signal_reaches_a_handler_that_is_not_an_interrupt_after_the_swap(
    tmp_path, monkeypatch, swap
):
    out = _old_output(tmp_path / "out")
    calls = []
    monkeypatch.setattr(
        staging, "between_swap_steps", lambda path: os.kill(os.getpid(), signal.SIGUSR1)
    )
    previous = signal.signal(signal.SIGUSR1, lambda *_: calls.append("USR1"))
    try:
        monkeypatch.setattr(staging, "_INTERRUPTS", (signal.SIGUSR1,))
        _replace(out)
    finally:
        signal.signal(signal.SIGUSR1, previous)
    assert calls == ["USR1"]
    assert _name(out) == "new" and _hidden(tmp_path) == []


def test_a_failed_second_rename_puts_the_old_output_back(tmp_path, monkeypatch):
    monkeypatch.setattr(staging, "_renameat2", None)
    out = _old_output(tmp_path / "out")

    def lose_the_build(path: Path) -> None:
        shutil.rmtree(staging.staging_path(out))

    monkeypatch.setattr(staging, "between_swap_steps", lose_the_build)
    with pytest.raises(staging.StagingError, match="cannot put the output in place"):
        _replace(out)
    assert _name(out) == "old" and _hidden(tmp_path) == []


def test_an_old_output_that_cannot_be_removed_is_reported_with_the_new_one_in_place(
    tmp_path, monkeypatch, caplog, swap
):
    out = _old_output(tmp_path / "out")
    remove = staging.remove_path

    def immutable(path: Path) -> None:
        if path == old_path(out):
            raise PermissionError(1, "Operation not permitted", str(path / "frames.csv"))
        remove(path)

    monkeypatch.setattr(staging, "remove_path", immutable)
    with caplog.at_level(logging.WARNING, logger="allo_mrad_ros.staging"):
        _replace(out)
    assert _name(out) == "new"
    assert _name(old_path(out)) == "old"  # whole, where the warning says
    assert _hidden(tmp_path) == [old_path(out).name]
    (message,) = [record.getMessage() for record in caplog.records]
    assert "new output is in place" in message and str(old_path(out)) in message


def _chattr(flag: str, path: Path) -> bool:
    if shutil.which("chattr") is None:
        return False
    return subprocess.run(["chattr", flag, str(path)], capture_output=True).returncode == 0


def test_bag_write_over_a_bag_with_an_immutable_file_reports_what_happened(tmp_path):
    """A real failure: ``chattr +i`` on the old bag's storage file (root; skipped where the
    file system has no such attribute)."""
    from rosbag_fixtures import write_tiny_sequence

    from rosbag_tools.writer import write_bag

    sequence = write_tiny_sequence(tmp_path / "seq", train=1)
    out = tmp_path / "bag"
    write_bag(sequence, out)
    (storage,) = out.glob("*.mcap")
    old = storage.read_bytes()
    if not _chattr("+i", storage):
        pytest.skip("no immutable attribute here")
    try:
        argv = ["write", str(sequence), str(out), "--overwrite", "--quiet"]
        done = subprocess.run(
            [sys.executable, "-m", "rosbag_tools", *argv],
            capture_output=True,
            text=True,
            timeout=600,
        )
        leftover = [p for p in tmp_path.iterdir() if ".old-" in p.name]
        for path in leftover:
            _chattr("-i", path / storage.name)
    finally:
        _chattr("-i", storage)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr and "cannot put" not in done.stderr
    (warning,) = [line for line in done.stderr.splitlines() if "warning" in line]
    assert len(leftover) == 1 and str(leftover[0]) in warning and "in place" in warning
    assert (leftover[0] / storage.name).read_bytes() == old
    assert (out / "metadata.yaml").is_file() and (out / storage.name).is_file()


def test_an_old_output_a_killed_process_left_aside_is_put_back_not_deleted(tmp_path):
    """A process killed (SIGKILL) between the two renames leaves nothing at the path; the
    next run puts the old output back, and only then applies the rule to it."""
    out = _old_output(tmp_path / "out")
    script = (
        "import os, signal, sys\n"
        "from pathlib import Path\n"
        "from allo_mrad_ros import staging\n"
        "staging._renameat2 = None\n"
        "staging.between_swap_steps = lambda out: os.kill(os.getpid(), signal.SIGKILL)\n"
        "with staging.staged_folder(Path(sys.argv[1])) as folder:\n"
        "    (folder / 'sequence.yaml').write_text('format: allo-sequence/1\\nname: new\\n')\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), *sys.path])}
    done = subprocess.run([sys.executable, "-c", script, str(out)], env=env, timeout=120)
    assert done.returncode == -signal.SIGKILL
    assert not out.exists() and any(".old-" in name for name in _hidden(tmp_path))
    staging.remove_stale(out)  # the next run's clean-up keeps it: nothing else is there
    assert any(".old-" in name for name in _hidden(tmp_path))
    with pytest.raises(TargetError, match="already holds a sequence"):
        check_target(out, SEQUENCE)
    assert _name(out) == "old"
    assert not any(".old-" in name for name in _hidden(tmp_path))
