"""The verdict of every bad-input case the fuzz tests generate, counted for the summary that
``test/fuzz/conftest.py`` prints at the end of the run (a module of its own: a test module
importing ``conftest`` by name gets whichever conftest is first on the path)."""

from collections import Counter

VERDICTS: Counter[tuple[str, str]] = Counter()
