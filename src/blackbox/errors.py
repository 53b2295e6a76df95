"""The one base of every error the black box raises on purpose.

Each failure the black box can explain has its own named subclass beside the code that
raises it (:class:`~blackbox.config.node.ConfigError`,
:class:`~blackbox.record.store.StorageError`, :class:`~blackbox.station.auth.StationAuthError`,
...), and its message is written for the person at the terminal. The command line catches
this base alone and prints ``error: <message>`` with exit code 2, never a traceback, so a
new error class needs no change to the command line. Where callers also expect a standard
exception (``LookupError`` for "no such thing"), a subclass derives from both.

This module imports nothing, so every layer, the configuration leaf included, can use it.
"""

from __future__ import annotations


class BlackBoxError(Exception):
    """An error whose message says what went wrong and where, fit to show to a user."""
