"""The README's Python example runs as written and prints what the README says it prints."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def readme_python_section() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index("\n## Python\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else None]


def first_python_block(markdown: str) -> str:
    """The first fenced ``python`` block of ``markdown``, as a program."""
    match = re.search(r"^```python\n(.*?)^```$", markdown, re.DOTALL | re.MULTILINE)
    assert match, "no ```python block"
    return match.group(1)


def test_the_block_is_read_whole():
    markdown = "text\n```python\nimport os\nprint(1)\n```\n```python\nprint(2)\n```\n"
    assert first_python_block(markdown) == "import os\nprint(1)\n"


def test_the_readme_example_renders_then_detects_as_it_says():
    section = readme_python_section()
    program = first_python_block(section)
    assert "Pipeline.open(" in program and ".process(" in program
    claimed = re.search(r"It prints `(True|False) (\d+) ([\d.]+)`", section)
    assert claimed, "the README says what the example prints"
    run = subprocess.run(
        [sys.executable, "-c", program],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        cwd=ROOT,
    )
    assert run.returncode == 0, run.stderr
    anomalous, area, share = run.stdout.split()
    assert anomalous == claimed.group(1) == "True"
    # The render (OSMesa or EGL, its version) may move the rim by a few pixels.
    assert abs(int(area) - int(claimed.group(2))) <= 0.1 * int(claimed.group(2))
    assert float(share) >= float(claimed.group(3)) - 0.05
