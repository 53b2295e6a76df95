"""How long a process waited for a CPU: the kernel's run-queue delay, per thread.

A process that is runnable but not running is neither slow by its own fault nor stopped:
the host has more runnable work than cores. Linux counts that wait for every thread in
``/proc/<pid>/task/<tid>/schedstat`` (the second field, nanoseconds spent on a run queue
waiting to run). It tells apart the three things a late message can mean:

* the black box's own threads waited (the black box starved): what it measured in that
  stretch is its own lateness, a measurement gap;
* a robot process on this host waited (the host starved it): its topics came slower
  because the host was saturated, not because the node misbehaved;
* neither waited: the robot really was slow, stalled (a stopped process is not runnable,
  so it waits for nothing) or dead (no process): a fault to judge.

``proc`` is the source boundary: tests give a directory of their own ``schedstat`` files
instead of ``/proc``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

PROC = Path("/proc")


@dataclass(frozen=True, slots=True)
class CpuWait:
    """One process's run-queue delay between two readings: ``worst`` the longest any one
    of its threads waited (seconds), ``total`` the sum over its threads, over ``span``
    seconds of wall time."""

    worst: float
    total: float
    span: float


def thread_delays(pid: int | str, proc: Path = PROC) -> dict[str, tuple[float, int]] | None:
    """Thread id -> (seconds it has waited on a run queue so far, times it was run); ``None``
    when the process is gone or its counters cannot be read (a kernel without schedstats,
    another host)."""
    # os-level calls, not pathlib: read at every poll for every thread of the black box
    # and of each local publisher (2.8x cheaper: 86 instead of 243 us for 13 threads)
    tasks = f"{os.fspath(proc)}/{pid}/task/"
    try:
        tids = os.listdir(tasks)
    except OSError:
        return None
    delays: dict[str, tuple[float, int]] = {}
    for tid in tids:
        try:
            fd = os.open(f"{tasks}{tid}/schedstat", os.O_RDONLY)
            try:
                fields = os.read(fd, 256).split()
            finally:
                os.close(fd)
            delays[tid] = (int(fields[1]) / 1e9, int(fields[2]))
        except (OSError, IndexError, ValueError):
            continue  # a thread that ended between the listing and the read
    return delays or None


class WaitMeter:
    """The run-queue delay of processes since the previous reading of each.

    The first reading of a pid gives no wait (nothing to compare with); a thread new since
    the previous reading counts from zero. A pid reused by another process is caught by
    the caller (the graph knows when a node's pid changes) through :meth:`forget`.
    """

    def __init__(self, proc: Path = PROC) -> None:
        self.proc = proc
        self._last: dict[str, tuple[float, dict[str, tuple[float, int]]]] = {}
        self.stretch: dict[str, float] = {}
        """Pid -> the longest mean wait per run of one of its threads at its latest reading:
        a lower bound of that thread's longest single wait since the reading before. Many
        short waits (a thread woken often on a busy host) keep it small; one long one not."""

    def since_last(self, pid: int | str, now: float) -> CpuWait | None:
        """The wait of ``pid``'s threads since its previous reading (at time ``now``)."""
        key = str(pid)
        then = self._last[key][0] if key in self._last else None
        waits = self.threads_since_last(pid, now)
        if waits is None or then is None:
            return None
        return CpuWait(max(waits.values(), default=0.0), sum(waits.values()),
                       max(0.0, now - then))

    def threads_since_last(self, pid: int | str, now: float) -> dict[str, float] | None:
        """Thread id -> seconds it waited since ``pid``'s previous reading (at time
        ``now``); ``None`` at the first reading or when the process is gone. Also sets
        :attr:`stretch`."""
        key = str(pid)
        counters = thread_delays(key, self.proc)
        if counters is None:
            self._last.pop(key, None)
            return None
        last = self._last.get(key)
        self._last[key] = (now, counters)
        if last is None:
            return None
        before = last[1]
        waits: dict[str, float] = {}
        stretch = 0.0
        for tid, (wait, runs) in counters.items():
            w0, r0 = before.get(tid, (0.0, 0))
            waits[tid] = max(0.0, wait - w0)
            stretch = max(stretch, waits[tid] / max(1, runs - r0))
        self.stretch[key] = stretch
        return waits

    def last_reading(self, pid: int | str) -> float | None:
        """The time of ``pid``'s previous reading, if any."""
        last = self._last.get(str(pid))
        return None if last is None else last[0]

    def forget(self, pid: int | str) -> None:
        self._last.pop(str(pid), None)
        self.stretch.pop(str(pid), None)


OWN_WAIT_LIMIT = 1.5
"""Seconds one of the black box's own threads may wait for a CPU within :data:`OWN_WINDOW`
(it got less than a quarter of the CPU it asked for) before what it measured in that
stretch counts as its own lateness (a gap of everything). Shorter waits do not move what it
measures: ROS 1 arrivals carry the kernel's receive time, ROS 2 samples their writers'
clocks, and ``poll`` already waits for late counts and reads (``READ_LIMIT``,
``TAKE_LIMIT``) and notices its own late wake-up (``clockwatch.PAUSE_LIMIT``), each
turning more than 1 s of lateness into a gap. Measured beside two CPU-bound processes at
load 12-25 (docs/evaluation-realtime.md): a bound of 0.5 s within 1 s made 123 gaps of
everything in 150 s, 1 s within 2 s 321 in 600 s (16-24 % of the time unjudged, one rate
fault missed), while none of the false alarms there came from the black box's lateness
alone."""

OWN_WINDOW = 2.0
"""Seconds over which the black box's own waits are added up."""

OWN_STRETCH = 0.5
"""Seconds the black box's most delayed thread must have waited at once (its mean wait per
run since the previous reading, a lower bound of its longest wait) for its waits to count
as starvation. At load 20 and ``nice 10`` its threads, woken dozens of times a second,
waited 1.5-1.7 s within 2 s in many short waits (0.1 s of running, 2.5 s of waiting in
10 s), which delays nothing it measures: with the sum alone a healthy hour had 126 gaps of
everything in its first 11 minutes."""

NODE_WAIT_LIMIT = 0.2
"""Seconds a thread of a robot process on this host may wait for a CPU within
:data:`WINDOW` before its topics' timing in that stretch counts as the host's load, not
the node's behaviour. Measured beside two CPU-bound processes on two cores
(docs/evaluation-realtime.md): the thesis robot's rospy nodes waited 0.2 s or more in 3-4 %
of seconds, and the one false alarm of a 600 s healthy run came 3 s after its publisher
waited 0.46 s."""

WINDOW = 1.0
"""Seconds over which a robot process's waits are added up (a few short waits make one
long delay)."""


@dataclass(frozen=True, slots=True)
class Starved:
    """A process found starved: its most delayed thread waited ``waited`` seconds over the
    last ``span`` seconds (the window, or longer when the readings before it were further
    apart: a reading after a long pause of the reader covers the whole pause)."""

    waited: float
    span: float


@dataclass(slots=True)
class _Window:
    """Per-thread waits of one process over a sliding window (monotonic times); each entry
    is (previous reading's time, this reading's time, thread -> wait in between)."""

    waits: list[tuple[float, float, dict[str, float]]]

    def add(self, then: float, now: float, waits: dict[str, float], window: float) -> Starved:
        """Add one reading's waits; the longest one thread waited within the window, and
        the span those waits cover."""
        self.waits.append((then, now, waits))
        self.waits = [e for e in self.waits if e[1] > now - window]
        total: dict[str, float] = {}
        for _, _, reading in self.waits:
            for tid, w in reading.items():
                total[tid] = total.get(tid, 0.0) + w
        span = max(window, now - min(e[0] for e in self.waits))
        return Starved(max(total.values(), default=0.0), span)


class StarvationWatch:
    """Whether the black box itself, or a robot process on this host, was starved of CPU
    since the previous check, from their threads' run-queue waits (:class:`WaitMeter`).

    A live source asks at every ``poll``: :meth:`own` for the black box (``pid`` ``self``),
    :meth:`nodes` for the local processes of the robot it watches. A process one of whose
    threads waited longer than its limit within its window is starved; a stopped process
    (``SIGSTOP``) is not runnable and waits for nothing, and a dead one has no counters, so
    neither is ever excused as starved: a stall or a kill is still the robot's fault.
    """

    def __init__(self, proc: Path = PROC, own_limit: float = OWN_WAIT_LIMIT,
                 node_limit: float = NODE_WAIT_LIMIT, window: float = WINDOW,
                 own_window: float = OWN_WINDOW, own_stretch: float = OWN_STRETCH,
                 self_pid: int | str = "self") -> None:
        self.meter = WaitMeter(proc)
        self.own_limit = own_limit
        self.node_limit = node_limit
        self.window = window
        self.own_window = own_window
        self.own_stretch = own_stretch
        self.self_pid = self_pid
        self._windows: dict[str, _Window] = {}

    def _waited(self, pid: int | str, now: float, window: float) -> Starved | None:
        then = self.meter.last_reading(pid)
        waits = self.meter.threads_since_last(pid, now)
        if waits is None or then is None:
            self._windows.pop(str(pid), None)
            return None
        return self._windows.setdefault(str(pid), _Window([])).add(then, now, waits, window)

    def own(self, now: float) -> Starved | None:
        """The black box's most delayed thread's wait within ``own_window``, if that is over
        ``own_limit`` and one of its threads just waited ``own_stretch`` s at once (``now``:
        a monotonic time)."""
        found = self._waited(self.self_pid, now, self.own_window)
        stretch = self.meter.stretch.get(str(self.self_pid), 0.0)
        if found is None or found.waited <= self.own_limit or stretch < self.own_stretch:
            return None
        return found

    def nodes(self, pids: dict[str, int], now: float) -> dict[str, Starved]:
        """Node -> its most delayed thread's wait within the window, for the nodes of
        ``pids`` (node -> pid, processes on this host) over ``node_limit``."""
        starved: dict[str, Starved] = {}
        for node, pid in pids.items():
            found = self._waited(pid, now, self.window)
            if found is not None and found.waited > self.node_limit:
                starved[node] = found
        for gone in self._windows.keys() - {str(p) for p in pids.values()} - {
                str(self.self_pid)}:
            del self._windows[gone]
            self.meter.forget(gone)
        return starved


def cpu_pressure(proc: Path = PROC) -> float | None:
    """The host's CPU pressure (``/proc/pressure/cpu``, "some" avg10: the share of the
    last 10 s in which some runnable task waited for a CPU, percent); ``None`` without PSI."""
    try:
        line = (proc / "pressure" / "cpu").read_text(encoding="ascii").splitlines()[0]
        return float(dict(f.split("=") for f in line.split()[1:])["avg10"])
    except (OSError, IndexError, KeyError, ValueError):
        return None
