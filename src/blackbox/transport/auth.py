"""Who may read a robot's log and run its built-in test: signed requests, per-station keys.

DDS Security would authenticate participants and encrypt the traffic, but the ``cyclonedds``
wheel this project uses ships no security plugins, and Debian's plugins belong to another
Cyclone version (docs/health.md, "What is protected"). So the two remote requests that
expose something (a log request reveals the whole health log, configuration text
included; run_IBIT makes the robot work) carry a signature instead:

* A station owns an Ed25519 key pair (``blackbox keygen``). The robot's configuration lists
  the public keys it trusts and what each may do (``logs``, ``ibit``)::

      transport:
        access:
          stations:
            - {name: depot, public_key: "<base64>", may: [logs, ibit]}
            - {name: laptop, public_key_file: laptop.pub, may: [logs]}

* :class:`RequestSigner` signs the canonical encoding (:func:`canonical`) of the request's
  fields, the robot id, the action, the station's name, an expiry time and a random nonce.
* :class:`RequestVerifier` on the robot checks the signature with the named station's
  key, the right, the robot id (a request for another robot cannot be replayed here), the
  expiry (at most :data:`MAX_VALIDITY` seconds ahead, not past) and that the nonce was not
  seen before its expiry (no replay). Anything else is refused with a reason.

The cryptography is the ``cryptography`` package's Ed25519; nothing here is hand-rolled.
The requests are authenticated, not secret, and the answers are neither signed nor
encrypted: see docs/health.md for exactly what that protects.
"""

from __future__ import annotations

import base64
import json
import os
import re
import secrets
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from blackbox.config.node import ConfigNode
from blackbox.errors import BlackBoxError
from blackbox.health.types import C_Request_Signature

ACTIONS = ("logs", "ibit")
VERSION = "blackbox-request-v1"
MAX_VALIDITY = 120.0
"""Seconds a signed request may be valid for; the verifier remembers nonces that long."""
DEFAULT_VALIDITY = 30.0
MAX_NONCES = 100_000
_NONCE = re.compile(r"[0-9a-f]{32}")
KEY_ENV = "BLACKBOX_STATION_KEY"
"""Environment variable naming a station's private key file, used when no key is given."""


class RequestAuthError(BlackBoxError):
    """A key file or an access list cannot be used; the message says why."""


@dataclass(frozen=True, slots=True)
class Credential:
    """What travels with a request: who signed it, until when, a nonce and the signature."""

    station: str
    expires_ns: int
    nonce: str
    signature: bytes

    @property
    def expires(self) -> float:
        return self.expires_ns / 1e9


@dataclass(frozen=True, slots=True)
class Verdict:
    allowed: bool
    station: str | None
    reason: str


def canonical(action: str, robot_id: str, request: Mapping[str, Any], station: str,
              expires_ns: int, nonce: str) -> bytes:
    """The bytes that are signed: a version tag and sorted, compact, ASCII JSON.

    Times are integer nanoseconds, so float formatting cannot differ between the signer
    and the verifier; ``request`` holds the request's own fields (ids, filters, limits).
    """
    body = {"action": action, "robot": robot_id, "request": dict(request), "station": station,
            "expires_ns": int(expires_ns), "nonce": nonce}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False)
    return f"{VERSION}\n{text}".encode("ascii")


# ---- keys --------------------------------------------------------------------------------


def public_key_text(key: Ed25519PublicKey) -> str:
    """A public key as base64 of its 32 raw bytes (what the robot's configuration lists)."""
    raw = key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return base64.b64encode(raw).decode("ascii")


def parse_public_key(text: str) -> Ed25519PublicKey:
    """A public key from base64 of 32 bytes, or a ``.pub`` line ``ed25519 <base64> [name]``."""
    parts = text.split()
    token = parts[1] if len(parts) >= 2 and parts[0] == "ed25519" else (parts[0] if parts
                                                                        else "")
    try:
        raw = base64.b64decode(token, validate=True)
        return Ed25519PublicKey.from_public_bytes(raw)
    except (ValueError, TypeError):
        raise RequestAuthError("not an Ed25519 public key (expected base64 of 32 bytes)") from None


def generate_key_pair(private_path: Path, name: str) -> Path:
    """Write a new station key: ``private_path`` (PEM, mode 0600) and ``<path>.pub``.

    Refuses to overwrite either file. Returns the public key file's path.
    """
    public_path = private_path.with_name(private_path.name + ".pub")
    for path in (private_path, public_path):
        if path.exists():
            raise RequestAuthError(f"{path} exists; it is not overwritten")
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    try:
        fd = os.open(private_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(pem)
        public_path.write_text(f"ed25519 {public_key_text(key.public_key())} {name}\n")
    except OSError as exc:
        raise RequestAuthError(f"cannot write the key: {exc}") from None
    return public_path


def station_trusted_by(base_config: Path, directory: Path, name: str) -> tuple[Path, Path]:
    """A new station key ``directory/<name>.key`` and a copy of ``base_config`` that trusts
    it for log requests and IBIT, ``directory/<name>-robot.yaml``; returns (key, config).

    For demos and tests that start their own robot and station; an old key of the same
    name in ``directory`` is replaced. ``base_config`` must not have a ``transport`` section.
    """
    key = directory / f"{name}.key"
    for old in (key, key.with_name(key.name + ".pub")):
        old.unlink(missing_ok=True)
    public = generate_key_pair(key, name)
    config = directory / f"{name}-robot.yaml"
    config.write_text(base_config.read_text() + f"\n# trusts the station key {public.name}\n"
                      "transport:\n  access:\n    stations:\n"
                      f"      - {{name: {name}, public_key_file: {public.name}, "
                      "may: [logs, ibit]}\n")
    return key, config


def load_private_key(path: Path) -> Ed25519PrivateKey:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise RequestAuthError(f"{path}: cannot read the key: {exc.strerror}") from None
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError) as exc:
        raise RequestAuthError(f"{path}: not a private key ({exc})") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise RequestAuthError(f"{path}: not an Ed25519 key")
    return key


# ---- the station side ------------------------------------------------------------------------


class RequestSigner:
    """Signs a station's requests. ``station`` is the name the robot knows the key by."""

    def __init__(self, key: Ed25519PrivateKey, station: str, *,
                 validity: float = DEFAULT_VALIDITY,
                 clock: Callable[[], float] = time.time) -> None:
        if not station:
            raise RequestAuthError("a signing station needs a name")
        if not 0 < validity <= MAX_VALIDITY:
            raise RequestAuthError(f"validity must be 0..{MAX_VALIDITY:g} s")
        self.key = key
        self.station = station
        self.validity = validity
        self.clock = clock

    @classmethod
    def from_file(cls, path: str | Path, station: str | None = None) -> RequestSigner:
        """The key at ``path``; the station's name defaults to the name in ``path.pub``,
        else the file's stem."""
        path = Path(path)
        key = load_private_key(path)
        if station is None:
            pub = path.with_name(path.name + ".pub")
            parts = pub.read_text().split() if pub.exists() else []
            station = parts[2] if len(parts) >= 3 else path.stem
        return cls(key, station)

    @classmethod
    def from_environment(cls) -> RequestSigner | None:
        """The key named by ``$BLACKBOX_STATION_KEY``, if set."""
        path = os.environ.get(KEY_ENV)
        return cls.from_file(path) if path else None

    @property
    def public_key(self) -> str:
        return public_key_text(self.key.public_key())

    def sign(self, action: str, robot_id: str, request: Mapping[str, Any]) -> Credential:
        expires_ns = int((self.clock() + self.validity) * 1e9)
        nonce = secrets.token_hex(16)
        message = canonical(action, robot_id, request, self.station, expires_ns, nonce)
        return Credential(self.station, expires_ns, nonce, self.key.sign(message))


# ---- the robot side ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class StationAccess:
    """One trusted station: its name, public key and what it may do."""

    name: str
    public_key: Ed25519PublicKey
    may: frozenset[str]


@dataclass(frozen=True, slots=True)
class AccessPolicy:
    """The stations a robot answers. Empty (the default): every request is refused."""

    stations: Mapping[str, StationAccess] = field(default_factory=dict)
    unsigned: frozenset[str] = frozenset()
    """Rights granted without a signature (a closed network, a bench): none by default."""

    @classmethod
    def of(cls, stations: Iterable[StationAccess],
           unsigned: Iterable[str] = ()) -> AccessPolicy:
        return cls({s.name: s for s in stations}, frozenset(unsigned))

    @classmethod
    def from_config(cls, node: ConfigNode | None, base_dir: Path) -> AccessPolicy:
        """The ``transport.access`` section (see the module docstring)."""
        if node is None:
            return cls()
        node.check_keys(["stations", "unsigned"])
        stations: list[StationAccess] = []
        unsigned = _rights(node, "unsigned") if node.get("unsigned") is not None else []
        for item in node["stations"].list() if node.get("stations") is not None else []:
            item.check_keys(["name", "public_key", "public_key_file", "may"])
            name = item["name"].str()
            if name in {s.name for s in stations}:
                raise item["name"].error(f"station {name!r} is listed twice")
            stations.append(StationAccess(name, _station_key(item, base_dir),
                                          frozenset(_rights(item, "may"))))
        return cls.of(stations, unsigned)


def _station_key(item: ConfigNode, base_dir: Path) -> Ed25519PublicKey:
    if (text := item.get("public_key")) is not None:
        where, value = text, text.str()
    elif (file := item.get("public_key_file")) is not None:
        path = Path(file.str())
        path = path if path.is_absolute() else base_dir / path
        try:
            where, value = file, path.read_text()
        except OSError as exc:
            raise file.error(f"cannot read {path}: {exc.strerror}") from None
    else:
        raise item.error("a station needs 'public_key' or 'public_key_file'")
    try:
        return parse_public_key(value)
    except RequestAuthError as exc:
        raise where.error(str(exc)) from None


def _rights(item: ConfigNode, key: str) -> list[str]:
    if item.get(key) is None:
        raise item.error(f"say what the station may do: '{key}: [{', '.join(ACTIONS)}]'")
    rights = list(item[key].str_list())
    for right in rights:
        if right not in ACTIONS:
            raise item[key].error(f"unknown right {right!r}; known: {', '.join(ACTIONS)}")
    return rights


class RequestVerifier:
    """Decides on the robot whether a signed request is answered.

    Thread-safe enough for its one caller (the DDS service thread); remembers the nonces of
    requests it allowed until they expire, at most :data:`MAX_NONCES` of them.

    ``nonce_file``: where the allowed nonces are also written (one ``expires_ns nonce`` line
    each, synced to disk before the request is answered) and read back at the next start,
    so a request captured before a restart of the robot is refused after it too. Without
    it they live in memory only. If the file cannot be written the request is refused:
    answering it could allow a replay later.
    """

    def __init__(self, robot_id: str, policy: AccessPolicy, *,
                 clock: Callable[[], float] = time.time,
                 nonce_file: Path | None = None) -> None:
        self.robot_id = robot_id
        self.policy = policy
        self.clock = clock
        self._nonces: dict[str, float] = {}
        self.refused = 0
        self.nonce_file = Path(nonce_file) if nonce_file is not None else None
        if self.nonce_file is not None:
            self._load_nonces(self.nonce_file)

    def verify(self, action: str, request: Mapping[str, Any],
               credential: Credential | None) -> Verdict:
        verdict = self._verify(action, request, credential)
        if not verdict.allowed:
            self.refused += 1
        return verdict

    def _verify(self, action: str, request: Mapping[str, Any],
                credential: Credential | None) -> Verdict:
        if credential is None or not credential.station:
            if action in self.policy.unsigned:
                return Verdict(True, None, "ok (unsigned requests allowed)")
            return Verdict(False, None, "unsigned request; this robot answers signed requests "
                                        "of the stations its configuration lists")
        station = self.policy.stations.get(credential.station)
        if station is None:
            return Verdict(False, None, "unknown station")
        now = self.clock()
        if not now < credential.expires <= now + MAX_VALIDITY:
            return Verdict(False, station.name, "expired or implausible expiry time")
        if not _NONCE.fullmatch(credential.nonce) or credential.nonce in self._nonces:
            return Verdict(False, station.name, "replayed or malformed nonce")
        try:
            message = canonical(action, self.robot_id, request, station.name,
                                credential.expires_ns, credential.nonce)
            station.public_key.verify(bytes(credential.signature), message)
        except (InvalidSignature, ValueError, TypeError):
            return Verdict(False, station.name, "bad signature")
        if action not in station.may:
            return Verdict(False, station.name, f"station {station.name} may not {action}")
        if not self._remember(credential.nonce, credential.expires, now):
            return Verdict(False, station.name, "too many requests; try again later")
        if not self._persist(credential.nonce, credential.expires_ns):
            return Verdict(False, station.name, "cannot record the nonce on the robot")
        return Verdict(True, station.name, "ok")

    def _load_nonces(self, path: Path) -> None:
        """The unexpired nonces of earlier starts; the file is rewritten with only those
        (atomically), so it never grows beyond what :data:`MAX_VALIDITY` keeps alive."""
        now = self.clock()
        try:
            lines = path.read_text(encoding="ascii", errors="replace").splitlines()
        except FileNotFoundError:
            lines = []
        except OSError as exc:
            raise RequestAuthError(f"{path}: cannot read the replay record: "
                                   f"{exc.strerror}") from None
        for line in lines:
            parts = line.split()
            if len(parts) != 2 or not parts[0].isdigit() or not _NONCE.fullmatch(parts[1]):
                continue  # a torn last line of a crash: its request was never answered
            expires = int(parts[0]) / 1e9
            if expires > now:
                self._nonces[parts[1]] = expires
        tmp = path.with_name(path.name + ".tmp")
        try:
            with open(tmp, "w", encoding="ascii") as fh:
                fh.writelines(f"{int(t * 1e9)} {n}\n" for n, t in self._nonces.items())
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except OSError as exc:
            raise RequestAuthError(f"{path}: cannot write the replay record: "
                                   f"{exc.strerror}") from None

    def _persist(self, nonce: str, expires_ns: int) -> bool:
        if self.nonce_file is None:
            return True
        try:
            with open(self.nonce_file, "a", encoding="ascii") as fh:
                fh.write(f"{int(expires_ns)} {nonce}\n")
                fh.flush()
                os.fsync(fh.fileno())
        except OSError:
            self._nonces.pop(nonce, None)
            return False
        return True

    def _remember(self, nonce: str, expires: float, now: float) -> bool:
        nonces = self._nonces
        if len(nonces) >= MAX_NONCES:
            for old in [n for n, t in nonces.items() if t <= now]:
                del nonces[old]
            if len(nonces) >= MAX_NONCES:  # never forget a live nonce: that would allow a replay
                return False
        nonces[nonce] = expires
        return True


# ---- on the wire -------------------------------------------------------------------------


def to_wire(credential: Credential | None) -> C_Request_Signature:
    """A credential as the IDL struct that requests carry (empty: unsigned)."""
    if credential is None:
        return C_Request_Signature()
    return C_Request_Signature(A_station=credential.station, A_expiresNs=credential.expires_ns,
                               A_nonce=credential.nonce, A_signature=list(credential.signature))


def from_wire(signed: C_Request_Signature) -> Credential | None:
    """The credential a request carries, ``None`` if unsigned; bounded so that a hostile
    sample cannot make the verifier work hard."""
    if not signed.A_station:
        return None
    return Credential(signed.A_station[:128], int(signed.A_expiresNs), signed.A_nonce[:64],
                      bytes(signed.A_signature[:128]))
