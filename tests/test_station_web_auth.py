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
                                                          free_failures=3, base_backoff=2.0),
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
    # throttled per (name, address): not this name elsewhere, not another name from here
    assert auth.retry_after("ana", "10.9.9.9") == 0
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
    auth.add_user("root2", PASSWORD, Role.ADMIN)
    auth.log_in("root1", "nope nope nope", "1.2.3.4")
    token = auth.log_in("root1", PASSWORD, "1.2.3.4").session_token
    assert token is not None
    auth.set_role("root2", Role.OPERATOR, by="root1", address="1.2.3.4")
    auth.log_out(token, "1.2.3.4")
    actions = [(e.action, e.outcome) for e in reversed(auth.audit_log())]
    assert actions == [("user.add", "ok"), ("user.add", "ok"), ("login", "refused"),
                       ("login", "ok"), ("user.role", "ok"), ("logout", "ok")]


def test_many_names_failing_from_one_address_do_not_throttle_another_name_there(
        auth: Auth) -> None:
    """A control room's consoles may share an address: one person's typos (or a guesser
    at one console) must not lock everybody there out."""
    for i in range(25):
        auth.log_in(f"guess{i}", "wrong password!", "10.0.0.3")
    for _ in range(3):
        auth.log_in("guess0", "wrong password!", "10.0.0.3")
    assert auth.retry_after("guess0", "10.0.0.3") > 0
    assert auth.retry_after("someone-else", "10.0.0.3") == 0


def test_back_off_is_capped_so_a_guesser_never_locks_a_name_for_good(
        auth: Auth, clock: Clock) -> None:
    auth.add_user("ana", PASSWORD, Role.VIEWER)
    longest = 0.0
    for _ in range(40):  # every attempt waits out its back-off, so each one is heard
        clock.now += auth.retry_after("ana", "10.0.0.9") + 0.01
        auth.log_in("ana", "wrong password!", "10.0.0.9")
        longest = max(longest, auth.retry_after("ana", "10.0.0.9"))
    assert longest <= auth.policy.max_backoff
    clock.now += auth.policy.max_backoff
    assert auth.log_in("ana", PASSWORD, "10.0.0.9").session is not None


@pytest.mark.parametrize("password, words", [
    (" " * 12, "only spaces"),
    ("ana.nurse", "at least 10"),
    ("nurse.ana.1", None),
    ("ana.nurse1", "user name"),
    ("1esrun.ana", "user name"),
    ("aaaaaaaaaaaa", "repeated"),
    ("abcdeabcde", "repeated"),
    ("1234567890", "breaches"),
    ("Password123!", "breaches"),
    ("!!iloveyou2024", "breaches"),
    ("x" * 2000, "at most 256"),
    ("ward three night shift", None),
])
def test_the_password_policy(auth: Auth, password: str, words: str | None) -> None:
    if words is None:
        auth.add_user("ana.nurse", password, Role.VIEWER)
        assert auth.log_in("ana.nurse", password, "x").session is not None
        return
    with pytest.raises(StationAuthError, match=words):
        auth.add_user("ana.nurse", password, Role.VIEWER)
    auth.add_user("ana.nurse", PASSWORD, Role.VIEWER)
    with pytest.raises(StationAuthError, match=words):
        auth.set_password("ana.nurse", password, by="admin", address="x")


def test_the_last_admin_can_be_neither_demoted_nor_removed(auth: Auth) -> None:
    auth.add_user("root1", PASSWORD, Role.ADMIN)
    with pytest.raises(StationAuthError, match="last admin"):
        auth.set_role("root1", Role.OPERATOR, by="root1", address="x")
    with pytest.raises(StationAuthError, match="last admin"):
        auth.remove_user("root1", by="cli", address="local")
    auth.add_user("root2", PASSWORD, Role.ADMIN)
    auth.set_role("root1", Role.VIEWER, by="root2", address="x")
    with pytest.raises(StationAuthError, match="last admin"):
        auth.remove_user("root2", by="cli", address="local")
    assert [(u.name, u.role) for u in auth.users()] == [("root1", Role.VIEWER),
                                                        ("root2", Role.ADMIN)]


def test_the_demo_account_is_renewed_although_it_is_the_only_admin(tmp_path: Path) -> None:
    from blackbox.cli.demo import DEMO_USER, demo_account
    from blackbox.cli.station import open_databases

    db = tmp_path / "demo.db"
    first = demo_account(db)
    second = demo_account(db)  # a second demo run on the same database
    assert first[0] == second[0] == DEMO_USER and first[1] != second[1]
    store, auth = open_databases(db)
    try:
        assert auth.log_in(DEMO_USER, second[1], "x").session is not None
        assert auth.log_in(DEMO_USER, first[1], "x").session is None
    finally:
        auth.close()
        store.close()


@pytest.mark.parametrize("value", ["0", "-1", "301"])
def test_a_login_backoff_outside_its_range_is_one_line_and_exit_2(
        tmp_path: Path, value: str) -> None:
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-m", "blackbox", "station", "--db",
                             str(tmp_path / "s.db"), "--bind", "127.0.0.1:0",
                             "--login-backoff", value], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"error: --login-backoff: {float(value):g} s is not within 0 < S <= 300"]
    assert not (tmp_path / "s.db").exists()  # refused before anything was opened
