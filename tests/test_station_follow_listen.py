"""``blackbox listen`` on a terminal: a live table redrawn in place, fed by the follower."""

from __future__ import annotations

import os
import pty
import re
import select
import subprocess
import sys
import time
from pathlib import Path

import pytest

from isolation import fresh_domain
from station_support import ScriptedBlackBox, dds_env

pytestmark = pytest.mark.dds


def _read_all(fd: int, proc: subprocess.Popen[bytes], timeout: float,
              until: bytes | None = None, out: bytes = b"") -> bytes:
    """What the terminal shows until the process ends (or ``until`` appears)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and (until is None or until not in out):
        ready, _, _ = select.select([fd], [], [], 0.2)
        if ready:
            try:
                chunk = os.read(fd, 65536)
            except OSError:
                break
            if not chunk:
                break
            out += chunk
        elif proc.poll() is not None:
            break
    return out


def test_listen_on_a_terminal_redraws_one_table_in_place(tmp_path: Path) -> None:
    domain = fresh_domain()
    box = ScriptedBlackBox("thesis", domain)
    try:
        box.send("ok")
        leader, follower = pty.openpty()
        env = {**dds_env(), "COLUMNS": "120", "LINES": "50", "TERM": "xterm-256color"}
        proc = subprocess.Popen(
            [sys.executable, "-m", "blackbox", "listen", "--domain", str(domain),
             "--backfill", "0", "--duration", "8"],
            stdin=follower, stdout=follower, stderr=follower, env=env)
        os.close(follower)
        try:
            shown = _read_all(leader, proc, 8, until=b"robot thesis")
            assert b"robot thesis" in shown, f"listen never showed the robot: {shown[-500:]!r}"
            box.send("fault")
            out = _read_all(leader, proc, 30, out=shown).decode("utf-8", "replace")
        finally:
            proc.wait(timeout=30)
            os.close(leader)
    finally:
        box.stop()
    assert proc.returncode == 0, out[-2000:]
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", out)
    assert "robot thesis" in text
    assert "/usb_cam" in text and "NOT_OPERATIONAL" in text
    assert "failure" in text and "camera publishes too slowly" in text
    assert "\x1b[2J" not in out  # no clearing and reprinting of whole screens
    assert re.search(r"\x1b\[\d*A", out)  # the cursor goes back up: redrawn in place
    # One table redrawn, not a scroll: far fewer lines written than redraws x table size.
    assert text.count("robot thesis") >= 2
