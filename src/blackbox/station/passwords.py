"""The station's password policy: what a password must not be before it is hashed.

An account on the station can make robots in a hospital run built-in tests and send their
logs, so a password is refused when it is

* shorter than :data:`MIN_PASSWORD` or longer than :data:`MAX_PASSWORD` characters (the
  log-in form reads at most :data:`MAX_PASSWORD`, so a longer one could never log in);
* the user name, the user name reversed, or the user name with only digits and symbols
  around it;
* one short piece repeated (``aaaaaaaaaa``, ``abcabcabca``, ten spaces) or made of fewer
  than :data:`MIN_DISTINCT` different characters;
* on the list of passwords seen most often in breaches that the ``zxcvbn`` package ships
  (about 30,000 of them), also when only its case differs or digits and symbols were
  added at either end of such a word.
"""

from __future__ import annotations

import functools
import re

MIN_PASSWORD = 10
MAX_PASSWORD = 256
MIN_DISTINCT = 5
_DECORATION = re.compile(r"^[\W\d_]*(.*?)[\W\d_]*$", re.DOTALL)


@functools.cache
def breached_passwords() -> frozenset[str]:
    """The breached-password list of ``zxcvbn`` (lower case)."""
    from zxcvbn.frequency_lists import FREQUENCY_LISTS  # type: ignore[import-untyped]

    words: list[str] = FREQUENCY_LISTS["passwords"]
    return frozenset(word.lower() for word in words)


def _core(text: str) -> str:
    """``text`` without the digits and symbols around it, in lower case."""
    match = _DECORATION.match(text.casefold())
    return match.group(1) if match else text.casefold()


def _smallest_period(text: str) -> int:
    """The length of the shortest piece that ``text`` repeats (``len(text)`` if none)."""
    for period in range(1, len(text)):
        if all(text[i] == text[i + period] for i in range(len(text) - period)):
            return period
    return len(text)


def password_problem(name: str, password: str) -> str | None:
    """Why ``password`` may not be ``name``'s password, or ``None`` when it may."""
    if len(password) < MIN_PASSWORD:
        return f"a password has at least {MIN_PASSWORD} characters"
    if len(password) > MAX_PASSWORD:
        return f"a password has at most {MAX_PASSWORD} characters"
    if not password.strip():
        return "a password cannot be only spaces"
    folded, user = password.casefold(), name.casefold()
    if user and (folded in (user, user[::-1]) or _core(password) in (user, user[::-1])):
        return "a password cannot be the user name"
    if len(set(folded)) < MIN_DISTINCT or _smallest_period(folded) <= len(folded) // 2:
        return "a password cannot be a few characters repeated"
    breached = breached_passwords()
    core = _core(password)
    if folded in breached or (len(core) >= 4 and core in breached):
        return "this password is on a list of passwords leaked in breaches; choose another"
    return None
