"""Resources that tests running in parallel (pytest-xdist workers) must not share.

Each worker gets a disjoint block of DDS domain ids, so a station in one worker never
follows another worker's robots and a ROS 2 robot never meets another worker's; temporary
directories are per worker already (pytest's ``tmp_path``) and ports come from the kernel
(bind to port 0). Without xdist the whole range is one block.
"""

from __future__ import annotations

import itertools
import os

FIRST_DOMAIN = 1
LAST_DOMAIN = 229
"""DDS domain ids used by tests (RTPS ports of domain 232 and above overflow 16 bits)."""


def worker() -> tuple[int, int]:
    """This process's xdist worker index and the number of workers (``(0, 1)`` alone)."""
    name = os.environ.get("PYTEST_XDIST_WORKER", "")
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    index = int(name[2:]) if name.startswith("gw") and name[2:].isdigit() else 0
    return index % max(1, count), max(1, count)


def _domains() -> itertools.cycle[int]:
    index, count = worker()
    size = (LAST_DOMAIN - FIRST_DOMAIN + 1) // count
    start = FIRST_DOMAIN + index * size
    # Start at a place that depends on the process, so a rerun right after a crashed one
    # does not meet its leftover processes on the same domain first.
    block = list(range(start, start + size))
    shift = os.getpid() % size
    return itertools.cycle(block[shift:] + block[:shift])


_next_domain = _domains()


def fresh_domain() -> int:
    """A DDS / ROS 2 domain id no other test of this run is using now."""
    return next(_next_domain)
