"""Bad-input fuzzing: the verdict of every generated case is counted and printed at the end.

``make fuzz`` runs many examples per property (``ALLO_FUZZ=1``); ``make test`` a few.
"""

import os
from collections import Counter

from hypothesis import HealthCheck, settings

VERDICTS: Counter[tuple[str, str]] = Counter()

settings.register_profile(
    "fuzz",
    max_examples=int(os.environ.get("ALLO_FUZZ_EXAMPLES", "300")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.register_profile(
    "quick",
    max_examples=20,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.load_profile("fuzz" if os.environ.get("ALLO_FUZZ") else "quick")


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
