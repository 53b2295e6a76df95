"""Whether the native TCPROS receive loop (``_tcpros.c``) is used, and why not.

The loop is compiled by the project's own install (``setup.py``, an optional extension);
where that was impossible (no C compiler, not Linux) or ``BLACKBOX_PURE_PYTHON=1`` is set
(tests run both paths), the reader works in Python, and says so once per process, so a
robot builder who wonders about the black box's CPU sees the reason at start.
"""

from __future__ import annotations

import importlib
import logging
import os
import threading
from types import ModuleType

log = logging.getLogger("blackbox.sources.ros1")

FORCE_PYTHON = "BLACKBOX_PURE_PYTHON"
"""Set to 1 to read TCPROS in Python even where the native loop is built."""

_said = False
_lock = threading.Lock()


def _load() -> tuple[ModuleType | None, str]:
    if os.environ.get(FORCE_PYTHON, "") not in ("", "0"):
        return None, f"{FORCE_PYTHON}={os.environ[FORCE_PYTHON]}"
    try:  # by name: the compiled module imports nothing of the package
        module = importlib.import_module("blackbox.sources.ros1._tcpros")
    except ImportError:
        return None, "the native loop is not built (no C compiler when scripts/setup.sh " \
                     "ran, or not Linux); install one and run scripts/setup.sh again"
    return module, ""


def native_loop() -> ModuleType | None:
    """The compiled module, or ``None`` (then one line says why, once per process)."""
    global _said
    module, why = _load()
    if module is None:
        with _lock:
            if not _said:
                _said = True
                log.warning("ros1: reading TCPROS in Python (slower per message): %s", why)
    return module
