"""Command-line options handed on to the function they configure, under one name.

The package's command lines name each option as the parameter of the function it sets
(``--wait-timeout`` sets ``wait_timeout``), so a command forwards options by name instead of
spelling every ``name=args.name`` pair out again.
"""

from __future__ import annotations

import argparse
from typing import Any


def keyword_options(args: argparse.Namespace, *names: str) -> dict[str, Any]:
    """The parsed options ``names`` as keyword arguments; ``--quiet`` becomes ``progress``."""
    options = {name: getattr(args, name) for name in names}
    if hasattr(args, "quiet"):
        options["progress"] = not args.quiet
    return options
