"""How a black box command ends on SIGTERM: unwind, then leave at once.

A service manager (systemd, a robot's launch system) sends SIGTERM and kills the process a
few seconds later. The command raises :class:`Terminated` so every ``finally`` block runs
(the recorder closes its log, files are flushed), and the command line then leaves with
``os._exit`` instead of tearing the interpreter down object by object, which took most of
a second with a large configuration loaded.
"""

from __future__ import annotations

import signal
from types import FrameType

EXIT_TERMINATED = 128 + signal.SIGTERM


class Terminated(SystemExit):
    """SIGTERM arrived: unwind (closing logs and files on the way) and exit 143."""

    def __init__(self) -> None:
        super().__init__(EXIT_TERMINATED)


def raise_terminated(signum: int, frame: FrameType | None) -> None:
    """A SIGTERM handler: end what is running now."""
    raise Terminated()
