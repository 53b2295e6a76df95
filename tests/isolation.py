"""Resources that tests running in parallel must not share: DDS / ROS 2 domain ids.

A domain id is machine-wide: two test processes that pick the same one see each other's
robots. Within one run the xdist workers are apart, but a second run on the same machine
(another checkout, a developer's ``make test-repeat`` beside CI) starts its workers with the
same ids. A robot of the other run then answers this run's station: a built-in test came
back as a refusal ("unknown station", no observations) from the other run's robot of the
same name. So each process claims the domains it uses with an advisory lock on a file per
domain (``$TMPDIR/blackbox-test-domains/<id>.lock``); the kernel drops the lock when the
process ends, so a crashed run leaves nothing to clean. A process holds its last
:data:`HELD` domains and lets the oldest go as it takes a new one, like the cycle it
replaces. Temporary directories are per test already (pytest's ``tmp_path``) and ports
come from the kernel (bind to port 0).
"""

from __future__ import annotations

import collections
import fcntl
import os
import tempfile
from pathlib import Path

FIRST_DOMAIN = 1
LAST_DOMAIN = 229
"""DDS domain ids used by tests (RTPS ports of domain 232 and above overflow 16 bits)."""

HELD = 12
"""Domains one process keeps claimed: the newest, so a domain is not handed to another
test while a process of a test a few tests ago may still be stopping on it."""

LOCKS = Path(tempfile.gettempdir()) / "blackbox-test-domains"


def worker() -> tuple[int, int]:
    """This process's xdist worker index and the number of workers (``(0, 1)`` alone)."""
    name = os.environ.get("PYTEST_XDIST_WORKER", "")
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    index = int(name[2:]) if name.startswith("gw") and name[2:].isdigit() else 0
    return index % max(1, count), max(1, count)


class DomainClaims:
    """Hands out domain ids no other process that claims through this class is using."""

    def __init__(self, locks: Path = LOCKS, held: int = HELD) -> None:
        self.locks = locks
        self.held = held
        self.claimed: collections.deque[tuple[int, int]] = collections.deque()
        index, count = worker()
        span = LAST_DOMAIN - FIRST_DOMAIN + 1
        size = span // count
        # Workers of one run start in their own stretch, at a place that depends on the
        # process, so a rerun right after a crashed one does not meet its leftovers first.
        self.next = index * size + os.getpid() % size

    def claim(self) -> int:
        """The next free domain id, now this process's until :data:`HELD` newer ones are."""
        self.locks.mkdir(parents=True, exist_ok=True)
        span = LAST_DOMAIN - FIRST_DOMAIN + 1
        mine = {domain for domain, _ in self.claimed}
        for step in range(span):
            offset = (self.next + step) % span
            domain = FIRST_DOMAIN + offset
            if domain in mine:
                continue
            fd = os.open(self.locks / f"{domain}.lock", os.O_CREAT | os.O_RDWR, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                continue
            self.next = offset + 1
            self.claimed.append((domain, fd))
            while len(self.claimed) > self.held:
                _, old = self.claimed.popleft()
                os.close(old)  # closing the only descriptor releases the lock
            return domain
        raise RuntimeError(f"all DDS domains {FIRST_DOMAIN}..{LAST_DOMAIN} are claimed by "
                           f"other test processes ({self.locks}); too many runs at once")

    def release(self) -> None:
        while self.claimed:
            os.close(self.claimed.popleft()[1])


_claims = DomainClaims()


def fresh_domain() -> int:
    """A DDS / ROS 2 domain id no other test of this or another run is using now."""
    return _claims.claim()
