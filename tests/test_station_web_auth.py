"""The station's accounts: argon2id hashes, sessions that end, back-off after failed log-ins,
CSRF tokens and the audit trail. A real SQLite file and a hand-driven clock."""

from __future__ import annotations

from pathlib import Path

import pytest

from blackbox.station.auth import Auth, AuthPolicy, Role, StationAuthError
from station_support import quick_auth

PASSWORD = "correct horse battery"


class Clock:
    def __init__(self) -> None:
        self.now = 1_800_000_000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def auth(tmp_path: Path, clock: Clock) -> Auth:
    return quick_auth(tmp_path / "station.db", AuthPolicy(idle_timeout=60, max_age=600,
                                                          free_failures=3, base_backoff=2.0,
                                                          free_failures_per_address=6),
                      clock=clock)


def test_no_account_exists_until_one_is_added(auth: Auth) -> None:
    assert auth.users() == []
    assert auth.log_in("admin", "admin", "127.0.0.1").session is None


def test_passwords_are_stored_as_argon2id_hashes(auth: Auth, tmp_path: Path) -> None:
    auth.add_user("ana", PASSWORD, Role.OPERATOR)
    import sqlite3

    stored = sqlite3.connect(tmp_path / "station.db").execute(
        "SELECT hash FROM web_users").fetchone()[0]
    assert stored.startswith("$argon2id$")
    assert PASSWORD not in stored


def test_bad_names_short_passwords_and_duplicates_are_refused(auth: Auth) -> None:
    with pytest.raises(StationAuthError):
        auth.add_user("<script>", PASSWORD, Role.VIEWER)
    with pytest.raises(StationAuthError):
        auth.add_user("bob", "short", Role.VIEWER)
    auth.add_user("bob", PASSWORD, Role.VIEWER)
    with pytest.raises(StationAuthError):
        auth.add_user("bob", PASSWORD, Role.ADMIN)
    with pytest.raises(ValueError, match="unknown role"):
        Role.parse("root")


def test_a_session_ends_after_idle_time_max_age_and_log_out(auth: Auth, clock: Clock) -> None:
    auth.add_user("ana", PASSWORD, Role.OPERATOR)
    result = auth.log_in("ana", PASSWORD, "10.0.0.1")
    assert result.session is not None and result.session_token
    token = result.session_token
    assert auth.session(token) is not None
    clock.now += 59
    assert auth.session(token) is not None  # touched: idle timer restarts
    clock.now += 61
    assert auth.session(token) is None

    token = auth.log_in("ana", PASSWORD, "10.0.0.1").session_token
    for _ in range(12):  # active all the time, but max_age still ends it
        clock.now += 55
        auth.session(token)
    assert auth.session(token) is None

    token = auth.log_in("ana", PASSWORD, "10.0.0.1").session_token
    assert token is not None
    auth.log_out(token, "10.0.0.1")
    assert auth.session(token) is None


def test_repeated_failures_back_off_exponentially_then_a_right_password_works(
        auth: Auth, clock: Clock) -> None:
    auth.add_user("ana", PASSWORD, Role.VIEWER)
    for _ in range(3):
        assert auth.log_in("ana", "wrong password!", "10.0.0.2").retry_after == 0
    throttled = auth.log_in("ana", PASSWORD, "10.0.0.2")
    assert throttled.session is None and 1.9 < throttled.retry_after <= 2.0  # even the right one
    clock.now += throttled.retry_after + 0.1
    assert auth.log_in("ana", "wrong password!", "10.0.0.2").retry_after == 0  # heard, refused
    assert 3.9 < auth.retry_after("ana", "10.0.0.2") <= 4.0  # doubled
    # another address is throttled for this user name too, another name from here is not
    assert auth.retry_after("ana", "10.9.9.9") > 0
    assert auth.retry_after("bob", "10.0.0.2") == 0
    clock.now += 5
    assert auth.log_in("ana", PASSWORD, "10.0.0.2").session is not None
    assert auth.retry_after("ana", "10.0.0.2") == 0


def test_csrf_token_belongs_to_the_session(auth: Auth) -> None:
    auth.add_user("ana", PASSWORD, Role.VIEWER)
    session = auth.log_in("ana", PASSWORD, "x").session
    other = auth.log_in("ana", PASSWORD, "x").session
    assert session is not None and other is not None
    assert Auth.csrf_matches(session, session.csrf)
    assert not Auth.csrf_matches(session, other.csrf)
    assert not Auth.csrf_matches(session, "")
    assert not Auth.csrf_matches(session, None)


def test_every_state_change_is_audited(auth: Auth) -> None:
    auth.add_user("root1", PASSWORD, Role.ADMIN)
    auth.log_in("root1", "nope nope nope", "1.2.3.4")
    token = auth.log_in("root1", PASSWORD, "1.2.3.4").session_token
    assert token is not None
    auth.set_role("root1", Role.OPERATOR, by="root1", address="1.2.3.4")
    auth.log_out(token, "1.2.3.4")
    actions = [(e.action, e.outcome) for e in reversed(auth.audit_log())]
    assert actions == [("user.add", "ok"), ("login", "refused"), ("login", "ok"),
                       ("user.role", "ok"), ("logout", "ok")]


def test_many_names_failing_from_one_address_throttle_the_address(auth: Auth) -> None:
    for i in range(6):
        auth.log_in(f"guess{i}", "wrong password!", "10.0.0.3")
    assert auth.retry_after("someone-else", "10.0.0.3") > 0
    assert auth.retry_after("someone-else", "10.0.0.4") == 0
