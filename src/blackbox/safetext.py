"""Text that came from a robot, made safe for the place it is written to.

Robot and node names, entity names and event texts are chosen by whoever runs the robot's
software (or whoever can publish on its bus). Three places treat some characters as
commands rather than text, and each gets one function here:

* a spreadsheet opening a CSV export runs a cell that starts with ``=``, ``+``, ``-``,
  ``@``, a tab or a carriage return as a formula (OWASP "CSV injection"):
  :func:`csv_cell` prefixes such a cell with ``'`` so it is shown as text;
* a terminal obeys escape sequences (clear the screen, set the window title, move the
  cursor, hide text): :func:`terminal_text` shows every control character as a visible
  escape such as ``\\x1b``;
* bidirectional overrides and zero-width characters make two different names look the
  same (a look-alike robot): :func:`hidden_character` finds them so that a configuration
  naming one can be refused.
"""

from __future__ import annotations

import io
import unicodedata
from typing import IO

CSV_FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")
"""The first characters that make a spreadsheet read a cell as a formula (OWASP)."""

_INVISIBLE_CATEGORIES = frozenset({"Cc", "Cf", "Zl", "Zp", "Co", "Cs", "Cn"})
"""Control, format (bidi marks and overrides, zero-width space/joiners, BOM), line and
paragraph separators, private-use, surrogate and unassigned characters."""


def csv_cell(value: object) -> object:
    """``value`` ready for :mod:`csv`: a string a spreadsheet would evaluate gets a leading
    ``'``; numbers and other values pass unchanged (a negative number is data, not a
    formula, and stays a number)."""
    if isinstance(value, str) and value.startswith(CSV_FORMULA_STARTS):
        return "'" + value
    return value


def _escape(char: str) -> str:
    code = ord(char)
    if code <= 0xFF:
        return f"\\x{code:02x}"
    if code <= 0xFFFF:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def terminal_text(text: object, keep: str = "") -> str:
    """``text`` with every control, format and separator character shown as an escape, so
    printing it cannot drive the terminal (ESC, CSI, OSC, BEL, backspace, carriage return,
    newlines inside a name, bidi overrides); characters in ``keep`` pass as they are."""
    return "".join(_escape(c) if c not in keep and unicodedata.category(c)
                   in _INVISIBLE_CATEGORIES else c for c in str(text))


class TerminalStream(io.TextIOBase):
    """A text stream for a terminal: lines pass, every other control character is shown
    as an escape (for exports written to standard output when that is a terminal)."""

    def __init__(self, terminal: IO[str]) -> None:
        super().__init__()
        self._terminal = terminal

    def write(self, text: str) -> int:
        self._terminal.write(terminal_text(text.replace("\r\n", "\n"), keep="\n"))
        return len(text)

    def flush(self) -> None:
        self._terminal.flush()


def hidden_character(text: str, allowed: str = "") -> str | None:
    """The first character of ``text`` that is invisible or reorders text (control, format,
    separator, private-use, unassigned), described as ``U+202E RIGHT-TO-LEFT OVERRIDE``;
    ``None`` when every character is visible or in ``allowed``."""
    for c in text:
        if c not in allowed and unicodedata.category(c) in _INVISIBLE_CATEGORIES:
            return f"U+{ord(c):04X} {unicodedata.name(c, 'control character')}"
    return None
