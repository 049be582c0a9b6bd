"""Verdicts of the bad-input sweep and its table: one row per case.

A case is *clean* when the program did what a careful user expects: refused the input with
one line naming the problem, a non-zero exit and nothing left behind (or, for input that is
merely unusual, accepted it with a correct result). Everything else is one of the named
failures below, most serious first.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

CLEAN = "clean"
TRACEBACK = "traceback"
CRASH = "crash"
PARTIAL = "partial output"
SILENT = "silent wrong"
UNCLEAR = "unclear error"
VERDICTS = (CLEAN, TRACEBACK, CRASH, PARTIAL, SILENT, UNCLEAR)
DESCRIPTIONS = {
    CLEAN: "one line naming the problem, non-zero exit, nothing left behind (or a valid result)",
    TRACEBACK: "a Python traceback reached the user or the log",
    CRASH: "killed by a signal, hung, or the node died / stopped processing",
    PARTIAL: "files left behind by a failed or interrupted command",
    SILENT: "exit 0 / accepted, with a wrong or altered result, or a problem never reported",
    UNCLEAR: "refused, but not in one line naming the problem (or refused valid input)",
}


@dataclass(frozen=True)
class Outcome:
    """The verdict of one case and why."""

    group: str
    case: str
    verdict: str
    detail: str = ""


def error_lines(stderr: str) -> list[str]:
    """The lines of ``stderr`` that a user reads as the error: argparse's usage block
    (``usage:`` and its indented continuation lines) and progress bars left out."""
    lines = []
    in_usage = False
    for line in stderr.splitlines():
        if not line.strip():
            continue
        if line.startswith("usage:"):
            in_usage = True
            continue
        if in_usage and line.startswith(" "):
            continue
        in_usage = False
        if "\r" in line or re.search(r"\d+%\|", line):
            continue  # tqdm
        if re.match(r"^[\w-]+( [\w-]+)?: skipping topic ", line):
            continue  # allo-bag play's warning about a message type not installed here
        lines.append(line)
    return lines


def classify_exit(
    returncode: int | None,
    stderr: str,
    keyword: str,
    left_behind: list[str],
    expect_error: bool,
    wrong_result: str | None = None,
) -> tuple[str, str]:
    """The verdict of a finished command-line case.

    ``returncode`` None means it had to be killed (hung); ``keyword`` is a regular expression
    the one error line must match; ``wrong_result`` a description when the command succeeded
    but its result is wrong.
    """
    if "Traceback (most recent call last)" in stderr:
        return TRACEBACK, _last_line(stderr)
    if returncode is None:
        return CRASH, "hung: killed after the time limit"
    if returncode < 0:
        return CRASH, f"killed by signal {-returncode}; stderr ends: {_last_line(stderr)[-160:]}"
    if left_behind:
        return PARTIAL, ", ".join(left_behind[:4]) + (" ..." if len(left_behind) > 4 else "")
    lines = error_lines(stderr)
    if expect_error:
        if returncode == 0:
            return SILENT, "exit 0 on bad input"
        if len(lines) != 1:
            return UNCLEAR, f"{len(lines)} error lines: " + " | ".join(lines[:3])
        if keyword and not re.search(keyword, lines[0]):
            return UNCLEAR, f"does not match /{keyword}/: {lines[0]}"
        return CLEAN, lines[0]
    if returncode != 0:
        return UNCLEAR, f"valid input refused (exit {returncode}): " + " | ".join(lines[:2])
    if wrong_result:
        return SILENT, wrong_result
    return CLEAN, "accepted"


def _last_line(text: str) -> str:
    lines = [line for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else ""


def counts(outcomes: list[Outcome]) -> Counter[str]:
    """Cases per verdict (every verdict present, zero included)."""
    total = Counter({verdict: 0 for verdict in VERDICTS})
    total.update(outcome.verdict for outcome in outcomes)
    return total


def table_text(outcomes: list[Outcome]) -> str:
    """The sweep as a plain-text table for the terminal, non-clean cases first."""
    ordered = sorted(outcomes, key=lambda o: (o.verdict == CLEAN, o.group, o.case))
    width = max((len(o.group) + len(o.case) for o in outcomes), default=20) + 3
    rows = [f"{o.group + ': ' + o.case:<{width}} {o.verdict:<15} {o.detail[:110]}" for o in ordered]
    total = counts(outcomes)
    rows.append("")
    rows.append(f"{len(outcomes)} cases: " + ", ".join(f"{v}: {n}" for v, n in total.items()))
    return "\n".join(rows)


def table_markdown(outcomes: list[Outcome]) -> str:
    """The sweep as a markdown report: counts per verdict, then every case."""
    total = counts(outcomes)
    lines = ["# Bad-input sweep", "", "| verdict | cases | meaning |", "|---|---|---|"]
    lines += [f"| {v} | {total[v]} | {DESCRIPTIONS[v]} |" for v in VERDICTS]
    lines += ["", "| group | case | verdict | detail |", "|---|---|---|---|"]
    for o in sorted(outcomes, key=lambda o: (o.verdict == CLEAN, o.group, o.case)):
        detail = o.detail.replace("|", "\\|")[:300]
        lines.append(f"| {o.group} | {o.case} | {o.verdict} | {detail} |")
    return "\n".join(lines) + "\n"


def write_reports(outcomes: list[Outcome], out: Path) -> None:
    """``sweep.json`` and ``sweep.md`` in ``out`` (created)."""
    out.mkdir(parents=True, exist_ok=True)
    document = {
        "counts": dict(counts(outcomes)),
        "cases": [asdict(o) for o in outcomes],
    }
    (out / "sweep.json").write_text(json.dumps(document, indent=2) + "\n")
    (out / "sweep.md").write_text(table_markdown(outcomes))
