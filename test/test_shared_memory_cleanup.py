"""Fast DDS files left in /dev/shm by killed processes are removed, and only those: a file a
live process maps or holds open, a recent one, one there before the run, and other files
stay."""

from __future__ import annotations

import mmap
import os
import subprocess
import sys

from harness.shared_memory import files_in_use, present, remove_orphans

OLD = 3600.0


def _make(directory, name, age_s=OLD, now=1e9):
    path = directory / name
    path.write_bytes(b"\0" * 4096)
    os.utime(path, (now - age_s, now - age_s))
    return path


def test_orphans_go_and_files_in_use_recent_or_foreign_stay(tmp_path):
    now = 1e9
    orphan = _make(tmp_path, "fastdds_0123456789abcdef")
    orphan_lock = _make(tmp_path, "fastdds_0123456789abcdef_el")
    old_name = _make(tmp_path, "fastrtps_port7411")
    semaphore = _make(tmp_path, "sem.fastdds_port7411_mutex")
    mapped = _make(tmp_path, "fastdds_fedcba9876543210")
    recent = _make(tmp_path, "fastdds_1111111111111111", age_s=1.0)
    other = _make(tmp_path, "pulse-shm-1234")
    before = _make(tmp_path, "fastdds_3333333333333333")  # an earlier run's or program's
    removed = remove_orphans(tmp_path, keep={before.name}, in_use={str(mapped)}, now=now)
    assert sorted(removed) == sorted([orphan, orphan_lock, old_name, semaphore])
    assert sorted(tmp_path.iterdir()) == sorted([mapped, recent, other, before])


def test_present_names_only_the_fast_dds_files(tmp_path):
    _make(tmp_path, "fastdds_4444444444444444")
    _make(tmp_path, "sem.fastrtps_port7411_mutex")
    _make(tmp_path, "pulse-shm-1234")
    assert present(tmp_path) == {"fastdds_4444444444444444", "sem.fastrtps_port7411_mutex"}
    assert present(tmp_path / "absent") == frozenset()


def test_a_file_a_live_process_maps_is_in_use(tmp_path):
    path = _make(tmp_path, "fastdds_2222222222222222", now=tmp_path.stat().st_mtime)
    with path.open("r+b") as handle, mmap.mmap(handle.fileno(), 4096):
        assert str(path) in files_in_use()
        assert remove_orphans(tmp_path, min_age_s=0.0) == []
    # Mapped and held by another process too.
    code = "import mmap,sys,time; f=open(sys.argv[1],'r+b'); m=mmap.mmap(f.fileno(),4096); "
    code += "f.close(); print('ready', flush=True); time.sleep(60)"
    child = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE)
    try:
        assert child.stdout.readline().strip() == b"ready"
        assert remove_orphans(tmp_path, min_age_s=0.0) == []
    finally:
        child.kill()
        child.wait()
    assert remove_orphans(tmp_path, min_age_s=0.0) == [path]


def test_a_missing_directory_removes_nothing(tmp_path):
    assert remove_orphans(tmp_path / "absent") == []
