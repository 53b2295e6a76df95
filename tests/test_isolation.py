"""Test processes never share a DDS domain, also across runs on the same machine
(tests/isolation.py): a second run's robot of the same name once answered this run's
station."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from isolation import FIRST_DOMAIN, LAST_DOMAIN, DomainClaims

HERE = Path(__file__).parent


def test_two_claimants_never_hold_the_same_domain(tmp_path: Path) -> None:
    first, second = DomainClaims(tmp_path, held=5), DomainClaims(tmp_path, held=5)
    second.next = first.next  # both start at the same place, as two runs' workers do
    try:
        a = [first.claim() for _ in range(5)]
        b = [second.claim() for _ in range(5)]
        assert len(set(a)) == 5 and not set(a) & set(b)
        assert all(FIRST_DOMAIN <= d <= LAST_DOMAIN for d in a + b)
    finally:
        first.release()
        second.release()


def test_a_claimant_keeps_only_its_newest_domains(tmp_path: Path) -> None:
    first, second = DomainClaims(tmp_path, held=2), DomainClaims(tmp_path, held=2)
    try:
        oldest = first.claim()
        first.claim()
        first.claim()  # the third lets the oldest go
        second.next = oldest - FIRST_DOMAIN
        assert second.claim() == oldest
    finally:
        first.release()
        second.release()


def test_a_domain_is_free_again_once_its_process_has_ended(tmp_path: Path) -> None:
    script = (f"import sys; sys.path.insert(0, {str(HERE)!r})\n"
              "from pathlib import Path\n"
              "from isolation import DomainClaims\n"
              f"claims = DomainClaims(Path({str(tmp_path)!r}))\n"
              "claims.next = 0\n"
              "print(claims.claim(), flush=True)\n"
              "sys.stdin.readline()\n")
    other = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    assert other.stdout is not None and other.stdin is not None
    held = int(other.stdout.readline())
    claims = DomainClaims(tmp_path)
    try:
        claims.next = held - FIRST_DOMAIN
        assert claims.claim() != held  # the other process holds it
        other.stdin.close()  # the other process ends without releasing anything itself
        other.wait(timeout=30)
        claims.release()
        claims.next = held - FIRST_DOMAIN
        assert claims.claim() == held
    finally:
        claims.release()
        if other.poll() is None:
            other.kill()
            other.wait(timeout=30)
