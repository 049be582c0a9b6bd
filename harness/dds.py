"""DDS domain ids for the tests' and benchmarks' ROS traffic on one machine.

Each run takes a domain of its own, so that runs side by side do not hear each other,
within 1..101: on Linux, the ports of domains 102-232 fall in the ephemeral port range,
where another socket may hold a participant's port (ROS 2's advice), and domain 0 is a
real system's default.
"""

from __future__ import annotations

import os

DOMAINS = 101
"""How many domains there are to take: ids 1..DOMAINS."""

WORKER_DOMAIN_STEP = 42
"""Domains between two test workers of one run (pytest-xdist; test/conftest.py). A test that
takes domains of its own steps 17 at a time from its worker's (the sweep's nodes); from one
worker to the next is 50 or 51 such steps (17 x 50 = 42 + 8 x 101), so it meets another
worker's domain only after fifty domains of its own."""


def process_domain(pid: int | None = None) -> int:
    """The domain of the process ``pid`` (this one's if None)."""
    return 1 + (os.getpid() if pid is None else pid) % DOMAINS


def domain_apart(domain: int, steps: int) -> int:
    """The domain ``steps`` places after ``domain``, within 1..DOMAINS: apart from it while
    ``steps`` is not a multiple of :data:`DOMAINS`."""
    return 1 + (domain - 1 + steps) % DOMAINS


def current_domain() -> int:
    """This process's ``ROS_DOMAIN_ID`` (1 when unset or empty)."""
    return int(os.environ.get("ROS_DOMAIN_ID", "1") or 1)
