"""The benchmarks' detection caches are keyed by the package's code: another code, another
key, so a cache made by other code is never read as this code's output."""

from __future__ import annotations

from pathlib import Path

from allo_mrad_ros.detector import MradParams
from benchmarks import decision_cache
from benchmarks.decision_cache import SequenceSplit, cache_dir
from benchmarks.source_digest import package_digest


def _tree(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


def test_the_digest_follows_every_source_file_and_only_them(tmp_path):
    files = {"a.py": "x = 1\n", "sub/b.py": "y = 2\n"}
    first = package_digest.__wrapped__(_tree(tmp_path / "one", files))
    assert first == package_digest.__wrapped__(_tree(tmp_path / "same", files))
    changed = {**files, "sub/b.py": "y = 3\n"}
    assert first != package_digest.__wrapped__(_tree(tmp_path / "changed", changed))
    added = {**files, "c.py": ""}
    assert first != package_digest.__wrapped__(_tree(tmp_path / "added", added))
    moved = {"a.py": "x = 1\n", "b.py": "y = 2\n"}
    assert first != package_digest.__wrapped__(_tree(tmp_path / "moved", moved))
    # Not source: data files beside the code leave the key as it is.
    other = _tree(tmp_path / "data", {**files, "notes.txt": "anything"})
    assert first == package_digest.__wrapped__(other)


def test_the_decision_cache_folder_changes_with_the_code(tmp_path, monkeypatch):
    sequence = tmp_path / "seq"
    sequence.mkdir()
    (sequence / "frames.csv").write_text("stamp_ns,split\n0,val\n")
    item = SequenceSplit(sequence, "val")
    monkeypatch.setattr(decision_cache, "package_digest", lambda: "0" * 16)
    before = cache_dir(tmp_path, item, None, MradParams())
    assert before == cache_dir(tmp_path, item, None, MradParams())
    monkeypatch.setattr(decision_cache, "package_digest", lambda: "1" * 16)
    assert cache_dir(tmp_path, item, None, MradParams()) != before
