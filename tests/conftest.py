"""Shared test fixtures and paths."""

from __future__ import annotations

import inspect
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from blackbox.app import RunOptions, build
from blackbox.model import Observation, Resource
from blackbox.sinks import SinkBase

# cpu_time: BLACKBOX_TEST_CPU=FILE gives CPU seconds per test; learned_ros2_diffdrive: one
# real ROS 2 robot learned once for the tests that learn on it.
pytest_plugins = ["cpu_time", "learned_ros2_diffdrive"]

# Byte-code caches on, for this process and every process a test starts: with
# PYTHONDONTWRITEBYTECODE set (as in some shells and containers) every `blackbox`
# subprocess compiled the package from source again (0.3 s of CPU a start) and every
# worker compiled and assertion-rewrote the test modules again (5 s of CPU each).
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT / "data" / "shared"
"""Vendored copies of the shared reference inputs (tug configs, thesis setup, DXC)."""


def described(condition: Callable[[], object]) -> str:
    """The source text of a waited-for condition (a lambda), for the failure message."""
    try:
        return inspect.getsource(condition).strip()
    except (OSError, TypeError):
        return repr(condition)


def wait_until(condition: Callable[[], object], what: str = "", timeout: float = 15.0,
               step: float = 0.05, state: Callable[[], object] | None = None) -> object:
    """Poll ``condition`` until it returns something true (and return that); fail the test
    with what it waited for (``what``, else the condition's source) after ``timeout``, and
    with what ``state`` returns then (what was seen instead)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            seen = "" if state is None else f"; saw {state()!r}"
            raise AssertionError(
                f"waited {timeout:g} s for {what or described(condition)}{seen}")
        time.sleep(step)


def wait_for(condition: Callable[[], bool], timeout: float, step: float = 0.05) -> bool:
    """Poll ``condition`` until it holds or ``timeout`` seconds pass (bounded waiting)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(step)
    return bool(condition())


@contextmanager
def black_box_running(options: RunOptions) -> Iterator[None]:
    """A black box built from ``options`` running in a thread, stopped on exit."""
    box = build(options)
    stop = threading.Event()
    thread = threading.Thread(target=box.run, args=(stop,), daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=5)


class Collected(SinkBase):
    """The observations of a black box running in another thread (:func:`black_box_running`),
    read by the test while it runs."""

    def __init__(self) -> None:
        self.observations: list[Observation] = []
        self.lock = threading.Lock()

    def on_observations(self, now: float, observations: Sequence[Observation]) -> None:
        with self.lock:
            self.observations.extend(observations)

    def about(self, observer: str, resource: Resource, since: float) -> list[Observation]:
        """The observations of ``observer`` on ``resource`` stamped at or after ``since``."""
        with self.lock:
            return [o for o in self.observations
                    if o.observer == observer and o.resource == resource and o.time >= since]


RECEIVE_PATHS = ("native", "python")


def _receive_path(request: Any, monkeypatch: Any) -> str:
    """The TCPROS receive path under test: the compiled loop or the Python fallback
    (``BLACKBOX_PURE_PYTHON``, inherited by reader processes). Where the loop is not built
    the native case is skipped; tests/test_ros1_native.py fails if it should have been."""
    from blackbox.sources.ros1.native import FORCE_PYTHON, native_loop

    path = str(request.param)
    if path == "python":
        monkeypatch.setenv(FORCE_PYTHON, "1")
    else:
        monkeypatch.delenv(FORCE_PYTHON, raising=False)
        if native_loop() is None:
            pytest.skip("the native TCPROS loop is not built here")
    return path


receive_path = pytest.fixture(params=RECEIVE_PATHS)(_receive_path)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In parallel workers, the tests measured slowest start first (tests/ordering.py);
    a run in one process keeps the file order, where module fixtures are set up once."""
    from ordering import expected_seconds, longest_first

    if os.environ.get("PYTEST_XDIST_WORKER"):
        items[:] = longest_first(items, expected_seconds())
