"""Helpers of the station tests: a disk that fills up, a scripted black box process,
accounts that are quick to check and operations that must not be reached."""

from __future__ import annotations

import atexit
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

import pytest
from argon2 import PasswordHasher

from blackbox.station.auth import Auth, AuthPolicy
from blackbox.station.store import StationStore
from blackbox.transport.auth import RequestSigner, station_trusted_by

HERE = Path(__file__).parent
DRIVER = HERE / "dds_blackbox_driver.py"


class FullDisk:
    """``tmpfs``: a real 2 MiB tmpfs that the test fills with a file (needs root, as in CI).
    ``page_limit``: where mounting is not allowed, SQLite's own ``max_page_count`` on the
    store's write connection makes every write that needs a new page fail with
    SQLITE_FULL, the same error a full disk gives; nothing is mocked."""

    def __init__(self, variant: str, directory: Path) -> None:
        self.variant = variant
        self.directory = directory
        self._filler = directory / "filler"

    def fill(self, store: StationStore) -> None:
        if self.variant == "tmpfs":
            with self._filler.open("wb", buffering=0) as fh, pytest.raises(OSError):
                while True:
                    fh.write(b"\0" * 65536)
                    fh.flush()
        else:
            pages = store._writes.connection().execute("PRAGMA page_count").fetchone()[0]
            store._writes.connection().execute(f"PRAGMA max_page_count = {pages}")

    def free(self, store: StationStore) -> None:
        if self.variant == "tmpfs":
            self._filler.unlink()
        else:
            store._writes.connection().execute("PRAGMA max_page_count = 1073741823")


FULL_DISK_VARIANTS = ["tmpfs", "page_limit"]


@contextmanager
def full_disk_in(variant: str, directory: Path) -> Iterator[FullDisk]:
    """A :class:`FullDisk` of ``variant`` under ``directory`` (tmpfs skips the test where
    mounting is not allowed)."""
    if variant == "page_limit":
        yield FullDisk("page_limit", directory)
        return
    mnt = directory / "small"
    mnt.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m",
                           f"station-{uuid.uuid4().hex[:8]}", str(mnt)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip()}); page_limit covers it")
    try:
        yield FullDisk("tmpfs", mnt)
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def quick_hasher() -> PasswordHasher:
    """Argon2 at its cheapest: the tests check logic, not the hashing cost."""
    return PasswordHasher(time_cost=1, memory_cost=8192, parallelism=1)


def quick_auth(path: Path, policy: AuthPolicy | None = None,
               clock: Callable[[], float] = time.time) -> Auth:
    """The station's accounts in ``path``, hashed with :func:`quick_hasher`."""
    return Auth(path, policy, clock, hasher=quick_hasher())


class Unreachable:
    """Operations a test must not reach: every call fails the test."""

    def request_logs(self, robot: str | int, *, entity: str | None = None,
                     characteristic: str | None = None, since: float | None = None,
                     until: float | None = None, kinds: Sequence[str] = (),
                     requested_by: str = "") -> int:
        raise AssertionError("request_logs reached")

    def run_ibit(self, robot: str | int, entity: str = "", requested_by: str = "") -> int:
        raise AssertionError("run_ibit reached")


def dds_env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("CYCLONEDDS_URI", None)  # the built-in loopback configuration applies
    return env


_KEYS = Path(tempfile.mkdtemp(prefix="blackbox-test-station-"))
atexit.register(shutil.rmtree, _KEYS, True)
THESIS_CONFIG = Path(__file__).resolve().parents[1] / "src/blackbox/configs/thesis.yaml"


def station_key_for_tests() -> Path:
    """The private key of the tests' station, made once per test session; robots started
    by the station tests trust it (a robot answers only the stations it lists)."""
    key = _KEYS / "test-station.key"
    if not key.exists():
        station_trusted_by(THESIS_CONFIG, _KEYS, "test-station")
    return key


def trusting_thesis_config() -> Path:
    """The thesis configuration trusting :func:`station_key_for_tests` (for ``blackbox run``)."""
    station_key_for_tests()
    return _KEYS / "test-station-robot.yaml"


def station_signer_for_tests() -> RequestSigner:
    return RequestSigner.from_file(station_key_for_tests())


class DriverBlackBox:
    """``tests/dds_blackbox_driver.py`` in its own process: ``send("ok" | "fault")``.
    ``allow``: public key file of a station -> the rights the robot grants it."""

    def __init__(self, robot: str, domain: int, store: Path | None = None,
                 partition: str = "blackbox", allow: Mapping[Path, str] | None = None,
                 key: Path | None = None, zenoh: str | None = None,
                 tls_ca: Path | None = None) -> None:
        cmd = [sys.executable, str(DRIVER), "--robot", robot, "--domain", str(domain),
               "--partition", partition]
        if zenoh is not None:
            cmd += ["--zenoh", zenoh]
        if tls_ca is not None:
            cmd += ["--tls-ca", str(tls_ca)]
        if key is not None:
            cmd += ["--key", str(key)]
        if store is not None:
            cmd += ["--store", str(store)]
        for public_key, rights in (allow or {}).items():
            cmd += ["--allow", f"{public_key}={rights}"]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, env=dds_env())
        assert self._line() == "ready"

    def _line(self) -> str:
        assert self.proc.stdout is not None
        return self.proc.stdout.readline().strip()

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        assert self._line() == f"done {command}"

    def stop(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.close()
                self.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait(timeout=10)


class ScriptedBlackBox(DriverBlackBox):
    """A :class:`DriverBlackBox` that answers one station's log requests and IBIT."""

    def __init__(self, robot: str, domain: int, store: Path | None = None,
                 trust: Path | None = None, key: Path | None = None,
                 zenoh: str | None = None, tls_ca: Path | None = None) -> None:
        """``trust``: the public key file of a station this robot answers (logs, ibit);
        default: the tests' station key (:func:`station_key_for_tests`). ``key``: the
        robot's own key (it then signs what it publishes)."""
        trust = trust or station_key_for_tests().with_suffix(".key.pub")
        super().__init__(robot, domain, store, allow={trust: "logs,ibit"}, key=key,
                         zenoh=zenoh, tls_ca=tls_ca)
