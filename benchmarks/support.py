"""What the process benchmarks share: CPU and peak memory of a process over a window,
stopping a process politely, the ``blackbox run`` summary rate and the usage table."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parent.parent
BLACKBOX = [sys.executable, "-m", "blackbox"]
THESIS_CONFIG = Path("/work/shared/reference/thesis-setup/observers_tests_11-20.yaml")
if not THESIS_CONFIG.exists():
    THESIS_CONFIG = ROOT / "tests" / "data" / "shared" / "thesis-setup" / \
        "observers_tests_11-20.yaml"


@dataclass
class Usage:
    """One process's CPU (user+system time over the window, 100 % = one core) and peak RSS
    (the kernel's high-water mark, VmHWM)."""

    what: str
    cpu_percent: float
    peak_rss_mb: float
    seconds: float
    note: str = ""


def peak_rss(pid: int) -> int:
    """The process's peak resident set size in bytes (0 if the kernel does not say)."""
    text = Path(f"/proc/{pid}/status").read_text()
    m = re.search(r"VmHWM:\s+(\d+) kB", text)
    return int(m.group(1)) * 1024 if m else 0


def measure(proc: subprocess.Popen[bytes], what: str, warmup: float, seconds: float) -> Usage:
    """After ``warmup`` seconds, the process's usage over the next ``seconds``."""
    return measure_together({what: proc}, warmup, seconds)[what]


def measure_together(procs: dict[str, subprocess.Popen[bytes]], warmup: float,
                     seconds: float) -> dict[str, Usage]:
    """After ``warmup`` seconds, each process's usage over the same next ``seconds``: the
    processes share every change of the machine's speed (a virtual machine's cores run
    fast and slow in phases of a minute or more), so their ratios are fair where a
    process measured after another is not."""
    handles = {what: psutil.Process(proc.pid) for what, proc in procs.items()}
    time.sleep(warmup)
    for what, proc in procs.items():
        if proc.poll() is not None:
            raise RuntimeError(f"{what} exited early with {proc.returncode}")
    t0 = time.monotonic()
    c0 = {what: sum(h.cpu_times()[:2]) for what, h in handles.items()}
    time.sleep(seconds)
    c1 = {what: sum(h.cpu_times()[:2]) for what, h in handles.items()}
    t1 = time.monotonic()
    return {what: Usage(what, 100.0 * (c1[what] - c0[what]) / (t1 - t0),
                        peak_rss(procs[what].pid) / 1e6, t1 - t0) for what in procs}


def stop(proc: subprocess.Popen[bytes], timeout: float = 10.0, group: bool = False) -> None:
    """SIGINT a running process (its whole process group with ``group``), so it closes
    cleanly and prints its summary; SIGKILL it if it has not exited after ``timeout``."""
    if proc.poll() is None:
        if group:
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def summary_rate(log: Path) -> float | None:
    """Messages per second over the run, from ``blackbox run``'s closing summary."""
    m = re.search(r"([\d.,]+) s observed, ([\d,]+) messages", log.read_text(errors="replace"))
    if not m:
        return None
    seconds = float(m.group(1).replace(",", ""))
    return int(m.group(2).replace(",", "")) / seconds if seconds > 0 else None


def print_usage(rows: Iterable[Usage]) -> None:
    """The machine, then one table row per measured process."""
    print(f"machine: {os.cpu_count()} cores, {psutil.virtual_memory().total / 2**30:.0f} GiB; "
          f"python {sys.version.split()[0]}")
    print("| what | CPU % of one core | peak RSS MB | note |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {r.what} | {r.cpu_percent:.1f} | {r.peak_rss_mb:.0f} | {r.note} |")
