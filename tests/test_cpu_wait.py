"""Run-queue waits read from ``schedstat`` files given at the source boundary: the black box
starved, a robot process starved by its host, and a stopped or dead process, which is never
excused as starved (docs/ros1.md, "measurement gaps")."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from blackbox.sources.cpu_wait import StarvationWatch, WaitMeter, cpu_pressure


class FakeProc:
    """A ``/proc`` of our own: per pid and thread, the nanoseconds waited on a run queue."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def wait(self, pid: int | str, tid: int, seconds: float, runs: int = 42) -> None:
        """``seconds`` waited so far over ``runs`` times the thread was run."""
        path = self.root / str(pid) / "task" / str(tid) / "schedstat"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"123456789 {round(seconds * 1e9)} {runs}\n", encoding="ascii")

    def gone(self, pid: int | str) -> None:
        shutil.rmtree(self.root / str(pid))


@pytest.fixture
def proc(tmp_path: Path) -> FakeProc:
    return FakeProc(tmp_path)


def test_the_worst_thread_counts_and_a_first_reading_gives_no_wait(proc: FakeProc) -> None:
    meter = WaitMeter(proc.root)
    proc.wait(7, 7, 1.0)
    proc.wait(7, 8, 2.0)
    assert meter.since_last(7, 10.0) is None  # nothing to compare with yet
    proc.wait(7, 7, 1.1)
    proc.wait(7, 8, 2.3)
    proc.wait(7, 9, 0.05)  # a thread new since the last reading counts from zero
    wait = meter.since_last(7, 11.0)
    assert wait is not None
    assert wait.worst == pytest.approx(0.3)
    assert wait.total == pytest.approx(0.45)
    assert wait.span == pytest.approx(1.0)


def test_the_black_box_waiting_over_its_limit_within_the_window_is_starved(
        proc: FakeProc) -> None:
    watch = StarvationWatch(proc.root, own_limit=0.5, own_window=1.0, own_stretch=0.0)
    proc.wait("self", 1, 0.0)
    assert watch.own(100.0) is None
    proc.wait("self", 1, 0.3)
    assert watch.own(100.4) is None  # 0.3 s: under the limit
    proc.wait("self", 1, 0.6)
    starved = watch.own(100.8)  # 0.3 + 0.3 within one second
    assert starved is not None and starved.waited == pytest.approx(0.6)
    assert starved.span == pytest.approx(1.0)
    proc.wait("self", 1, 0.9)
    assert watch.own(102.5) is None  # 0.3 s in the last second: under it again


def test_a_node_the_host_starves_is_told_apart_from_a_stopped_or_dead_one(
        proc: FakeProc) -> None:
    watch = StarvationWatch(proc.root, node_limit=0.2, window=1.0)
    pids = {"/audio_capture": 41, "/usb_cam": 42, "/Signal_generator": 43}
    for pid in pids.values():
        proc.wait(pid, pid, 5.0)
    assert watch.nodes(pids, 0.0) == {}
    proc.wait(41, 41, 5.25)  # runnable, no core for a quarter second: the host's load
    proc.wait(42, 42, 5.0)  # SIGSTOP: not runnable, so it waits for nothing
    proc.gone(43)  # killed: no counters
    starved = watch.nodes(pids, 0.5)
    assert list(starved) == ["/audio_capture"]
    assert starved["/audio_capture"].waited == pytest.approx(0.25)
    proc.wait(41, 41, 5.25)
    assert watch.nodes(pids, 2.0) == {}  # no more waiting: its timing is judged again


def test_cpu_pressure_is_read_from_the_hosts_psi_file_or_is_unknown(proc: FakeProc) -> None:
    assert cpu_pressure(proc.root) is None
    (proc.root / "pressure").mkdir()
    (proc.root / "pressure" / "cpu").write_text(
        "some avg10=23.29 avg60=10.94 avg300=21.17 total=31561703568\n"
        "full avg10=0.00 avg60=0.00 avg300=0.00 total=0\n", encoding="ascii")
    assert cpu_pressure(proc.root) == pytest.approx(23.29)


def test_the_real_proc_of_this_process_can_be_read() -> None:
    """The counters exist on this kernel (else every rule here is silently off)."""
    meter = WaitMeter()
    assert meter.since_last("self", 0.0) is None
    wait = meter.since_last("self", 1.0)
    assert wait is not None and wait.worst >= 0.0


def test_waits_of_different_threads_are_not_added_into_one(proc: FakeProc) -> None:
    """Two threads each waiting 0.6 s within the window is no thread waiting 1.2 s."""
    watch = StarvationWatch(proc.root, own_limit=1.0, own_window=2.0, own_stretch=0.0)
    proc.wait("self", 1, 0.0)
    proc.wait("self", 2, 0.0)
    assert watch.own(10.0) is None
    proc.wait("self", 1, 0.6)
    assert watch.own(10.5) is None
    proc.wait("self", 2, 0.6)
    assert watch.own(11.0) is None
    proc.wait("self", 2, 1.1)
    starved = watch.own(11.5)
    assert starved is not None and starved.waited == pytest.approx(1.1)


def test_a_wait_read_after_a_long_pause_spans_the_pause_not_the_window(
        proc: FakeProc) -> None:
    """Read 3 s after the previous reading (the reader itself paused), a 2.5 s wait is 2.5 s
    within 3 s: the gap must reach back over the whole stretch, not the last second."""
    watch = StarvationWatch(proc.root, node_limit=0.2, window=1.0)
    proc.wait(41, 41, 0.0)
    assert watch.nodes({"/audio_capture": 41}, 10.0) == {}
    proc.wait(41, 41, 2.5)
    starved = watch.nodes({"/audio_capture": 41}, 13.0)["/audio_capture"]
    assert starved.waited == pytest.approx(2.5)
    assert starved.span == pytest.approx(3.0)


def test_many_short_waits_of_the_black_box_are_no_starvation_one_long_one_is(
        proc: FakeProc) -> None:
    """1.6 s of waiting within 2 s spread over 40 runs (a thread woken often on a busy
    host: each run a little late) delays nothing the black box measures; 0.8 s before one
    run is a thread that did not run for most of a second at a time."""
    watch = StarvationWatch(proc.root)  # the defaults: 1.5 s within 2 s, 0.5 s at once
    proc.wait("self", 1, 0.0, runs=100)
    assert watch.own(0.0) is None
    proc.wait("self", 1, 0.8, runs=120)
    assert watch.own(1.0) is None
    proc.wait("self", 1, 1.6, runs=140)
    assert watch.own(2.0) is None  # 1.6 s within 2 s, but 0.04 s per run
    proc.wait("self", 1, 2.4, runs=141)
    starved = watch.own(3.0)  # 0.8 s at once, 1.6 s within the last 2 s
    assert starved is not None and starved.waited == pytest.approx(1.6)
