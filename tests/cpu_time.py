"""Per-test CPU seconds, for finding what makes the suite CPU-bound.

With 2 cores and 3 workers, the suite's wall time is bounded below by its CPU time over
two; ``--durations`` shows only wall seconds, which for most slow tests are time spent
waiting on robots. With ``BLACKBOX_TEST_CPU=FILE`` set, every test appends one line to
FILE: CPU seconds (the pytest process, its threads and every child process it reaped),
wall seconds and node id, setup to teardown. Children not yet reaped when the test ends
(a process left to a module fixture) are counted in the test that reaps them.
"""

from __future__ import annotations

import os
import resource
import time
from collections.abc import Generator
from pathlib import Path

import pytest

ENVIRONMENT = "BLACKBOX_TEST_CPU"


def cpu_seconds() -> float:
    """User and system CPU of this process and its reaped children."""
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        usage = resource.getrusage(who)
        total += usage.ru_utime + usage.ru_stime
    return total


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item) -> Generator[None, None, None]:
    target = os.environ.get(ENVIRONMENT)
    if not target:
        yield
        return
    cpu, wall = cpu_seconds(), time.monotonic()
    yield
    line = f"{cpu_seconds() - cpu:.2f} {time.monotonic() - wall:.2f} {item.nodeid}\n"
    with Path(target).open("a", encoding="utf-8") as out:
        out.write(line)
