"""The user documents speak of the software, not of how it was made: no issue numbers, no
sittings or sessions, no earlier trees, no paths of one machine; the README stays short."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README_MAX_LINES = 400

FORBIDDEN = {
    "an issue number": re.compile(r"\bissues?[\s_-]*#?\s*\d{1,2}\b", re.IGNORECASE),
    "an issue reference (#NN)": re.compile(r"(?<![\w&/#])#\d{1,3}\b"),
    "a session or sitting": re.compile(r"\b(sessions?|sittings?)\b", re.IGNORECASE),
    "an earlier tree": re.compile(r"\b(earlier|previous|old)\s+trees?\b", re.IGNORECASE),
    "a machine's absolute path": re.compile(r"(?<![\w.$~])/(work|root|home)/"),
}


def _documents() -> list[Path]:
    """README.md and every text file under docs/ (images and other binaries skipped)."""
    files = [ROOT / "README.md"]
    for path in sorted((ROOT / "docs").rglob("*")):
        if path.is_file() and b"\0" not in path.read_bytes()[:4096]:
            files.append(path)
    return files


def _findings(text: str) -> list[str]:
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        for what, pattern in FORBIDDEN.items():
            match = pattern.search(line)
            if match:
                found.append(f"line {number}: {what} ({match.group(0)!r})")
    return found


def test_there_are_documents_under_docs():
    names = {path.name for path in _documents()}
    for page in ("node.md", "detector.md", "evaluation.md", "performance.md", "distro.md"):
        assert page in names
    assert "failure-behaviour.md" in names


@pytest.mark.parametrize("path", _documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_document_does_not_tell_how_it_was_made(path):
    assert _findings(path.read_text(encoding="utf-8")) == []


def test_readme_is_at_most_400_lines():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines <= README_MAX_LINES


@pytest.mark.parametrize(
    "text",
    [
        "as issue 15 asked",
        "before issue 11",
        "Issue-7's target",
        "see #12",
        "the third session",
        "a second sitting",
        "the earlier tree",
        "in /home/someone/ws/data",
    ],
)
def test_the_check_catches_history(text):
    assert _findings(text)


@pytest.mark.parametrize(
    "text",
    [
        "## Parameters",
        "[QoS](#qos)",
        "issue the command",
        "source /opt/ros/$ROS_DISTRO/setup.bash",
        "`mrad.<name>`, grid 8, 1.0 issues",
    ],
)
def test_the_check_lets_ordinary_text_through(text):
    assert _findings(text) == []
