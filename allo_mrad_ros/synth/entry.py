"""The ``allo-synth`` entry point: SIGINT and SIGTERM are interrupts from its first line on.

The command-line module imports the renderer, trimesh and the generator, which takes
seconds on a loaded machine; a SIGTERM in that time would otherwise end the process by the
signal's default action instead of the documented exit status 130.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from allo_mrad_ros.staging import run_interruptible


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``allo-synth`` with ``argv`` (default: the process arguments); the exit status."""

    def load() -> Callable[[], int]:
        from allo_mrad_ros.synth.cli import main as cli_main

        return lambda: cli_main(argv)

    return run_interruptible("allo-synth", load)


if __name__ == "__main__":
    import sys

    sys.exit(main())
