"""Bad-input fuzzing: the verdict of every generated case is counted and printed at the end.

``make fuzz`` runs many examples per property (``ALLO_FUZZ=1``); ``make test`` a few (the
Hypothesis profiles are set in ``test/conftest.py``).
"""

from collections import Counter

from fuzz_verdicts import VERDICTS


def pytest_terminal_summary(terminalreporter):
    if not VERDICTS:
        return
    terminalreporter.section("bad-input fuzz verdicts")
    totals: Counter[str] = Counter()
    for (target, verdict), count in sorted(VERDICTS.items()):
        terminalreporter.write_line(f"{target:<16} {verdict:<18} {count}")
        totals[verdict] += count
    terminalreporter.write_line(
        "total            " + ", ".join(f"{v}: {n}" for v, n in sorted(totals.items()))
    )
