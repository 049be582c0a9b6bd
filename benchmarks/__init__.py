"""Benchmarks that print figures and write them to ``reports/`` (run by ``make bench-*``).

Not installed: run them from the repository root as ``python -m benchmarks.<name>``.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path


def write_report(path: Path, report: object) -> None:
    """Write a benchmark's figures as indented JSON (creating the folder) and say where."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")
    print(f"written: {path}")


def finish(path: Path, report: object) -> int:
    """Write a command's report (:func:`write_report`) and return its exit status, 0."""
    write_report(path, report)
    return 0


def machine_facts() -> dict[str, object]:
    """CPU count, machine and Python version, for a report's figures to be read against."""
    return {
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "python": platform.python_version(),
    }
