"""The station's gate: what an enrolled robot did not sign is never shown.

Every sample the follower takes passes :meth:`SampleGate.offer` first:

* Samples under the resource id of a robot that is not enrolled pass unchanged (and are
  counted ``unauthenticated``): a plain UCMS robot or one not yet enrolled keeps working.
* Samples of an enrolled robot pass only with a valid signature
  (``BlackBox_Sample_Signature``, :mod:`blackbox.transport.provenance`) made with the
  enrolled key over exactly these bytes. A sample whose signature has not arrived is held
  up to :data:`SIGNATURE_WAIT` seconds (the robot writes the signature first, so it is
  usually there already; :data:`FIRST_SIGNATURE_WAIT` while none of the robot's signatures
  has come yet, as for a station joining late); then it is rejected as ``unsigned``.
  Later samples of the same instance wait behind it, so states are shown in the order
  the robot wrote them; one whose signature never came but that a newer signed sample of
  its instance replaces is dropped as ``superseded`` (a state changing faster than the
  link: not an alarm).
* A signature that does not verify with the enrolled key is ``forged``.
* A signed state older than one already shown for the same instance (signing time, then
  the per-boot counter) is never shown: ``replayed`` if it was shown before (a captured
  OPERATIONAL cannot undo a later FAILED), else ``superseded`` (it came late).

Each rejection is counted (:class:`TrustStats`) and reported through ``on_problem`` (the
store's problems, shown on every page). The follower separately flags two DDS
participants writing under one robot's resource id at once (:class:`WriterWatch`).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from blackbox.health.extension import C_Sample_Signature
from blackbox.health.ids import robot_resource_id
from blackbox.transport.provenance import (
    SignedSample,
    digest,
    public_key_of,
    raw_public_key,
    verify_sample_signature,
)

SIGNATURE_WAIT = 2.0
"""Seconds a sample of an enrolled robot waits for its signature before it is rejected."""
FIRST_SIGNATURE_WAIT = 30.0
"""Seconds a sample waits while no signature of its robot has come at all. A station that
joins late matches the robot's signature writer on its own, under load seconds after the
state writers; the durable signatures then come all at once. Until then the wait is not
:data:`SIGNATURE_WAIT`, or a state the robot will not write again would be rejected."""
MAX_HELD = 10_000
MAX_VERIFIED = 50_000
MAX_INSTANCES = 200_000
WRITER_OVERLAP = 30.0
"""Two participants writing one robot's samples within this many seconds, both still on
the domain, are two writers claiming one robot."""


@dataclass(slots=True)
class TrustStats:
    verified: int = 0
    forged: int = 0
    """Signatures that did not verify with the enrolled key."""
    unsigned: int = 0
    """Samples of an enrolled robot with no valid signature in time (rejected)."""
    replayed: int = 0
    """Signed samples shown before and sent again after a newer one (rejected)."""
    superseded: int = 0
    """Samples older than one already shown, or replaced before their signature came."""
    unauthenticated: int = 0
    """Samples of robots that are not enrolled (shown, unauthenticated)."""
    second_writers: int = 0


Keys = Callable[[], dict[int, tuple[str, Ed25519PublicKey]]]
"""Resource id -> (robot id, enrolled key), as ``RobotKeys.by_resource``."""


@dataclass(slots=True)
class _Held:
    arrived: float
    topic: str
    sample: Any
    rid: int
    digest: bytes
    instance: tuple[str, int, int]


def _source(sample: Any) -> tuple[int, int]:
    return (int(sample.A_sourceID.A_resourceId), int(sample.A_sourceID.A_instanceId))


class SampleGate:
    """Admits what enrolled robots signed; see the module docstring. Single-threaded:
    the follower's reading thread is its only caller."""

    def __init__(self, keys: Keys, on_problem: Callable[[str, str, str], None], *,
                 on_key_seen: Callable[[str, Ed25519PublicKey], None] | None = None,
                 wait: float = SIGNATURE_WAIT) -> None:
        self.keys = keys
        self.on_problem = on_problem
        """Called with (robot id, kind, message); kind is forged, unsigned or replayed."""
        self.on_key_seen = on_key_seen
        self.wait = wait
        self.stats = TrustStats()
        self._verified: OrderedDict[tuple[int, bytes], SignedSample] = OrderedDict()
        self._last: OrderedDict[tuple[str, int, int], tuple[int, int]] = OrderedDict()
        self._held: list[_Held] = []
        self._held_per_instance: dict[tuple[str, int, int], int] = {}
        self._shown: OrderedDict[tuple[int, bytes], None] = OrderedDict()
        self._keys_seen: set[tuple[str, bytes]] = set()
        self._signing: dict[int, float] = {}
        """Robots whose signatures have come: when the first was taken (stamped by the next
        call that knows the time; until then in ``_unstamped``)."""
        self._unstamped: list[int] = []

    def enrolled(self, rid: int) -> tuple[str, Ed25519PublicKey] | None:
        return self.keys().get(rid)

    def signature(self, sig: C_Sample_Signature) -> None:
        """Take one signature sample: remember what it vouches for, or count a forgery."""
        rid = int(sig.A_sourceID.A_resourceId)
        enrolled = self.enrolled(rid)
        if enrolled is None:
            self._note_key(rid, sig)
            return
        robot_id, key = enrolled
        signed = verify_sample_signature(key, robot_id, sig)
        if signed is None:
            self.stats.forged += 1
            self.on_problem(robot_id, "forged", f"{robot_id}: a signature on "
                            f"{sig.A_topic[:64]!r} does not verify with the robot's enrolled "
                            "key; the sample it vouches for is not shown")
            return
        if rid not in self._signing and rid not in self._unstamped:
            self._unstamped.append(rid)
        self._verified[(rid, signed.digest)] = signed
        while len(self._verified) > MAX_VERIFIED:
            self._verified.popitem(last=False)

    def offer(self, topic: str, sample: Any, now: float) -> bool:
        """``True``: handle ``sample`` now; ``False``: held for its signature or rejected."""
        rid = int(sample.A_sourceID.A_resourceId)
        self._stamp(now)
        if self.enrolled(rid) is None:
            self.stats.unauthenticated += 1
            return True
        sample_digest = digest(sample)
        signed = self._verified.get((rid, sample_digest))
        instance = (topic, *_source(sample))
        if signed is None or instance in self._held_per_instance:
            if len(self._held) >= MAX_HELD:
                self._reject_unsigned(rid, topic)
                return False
            self._held.append(_Held(now, topic, sample, rid, sample_digest, instance))
            self._held_per_instance[instance] = self._held_per_instance.get(instance, 0) + 1
            return False
        return self._in_order(signed, topic, sample)

    def released(self, now: float) -> list[tuple[str, Any]]:
        """Held samples that may be shown now, in arrival order; see the module docstring
        for those dropped (superseded) or rejected (unsigned after the wait)."""
        self._stamp(now)
        verified = [self._verified.get((h.rid, h.digest)) for h in self._held]
        newest_signed = {h.instance: i for i, (h, v) in enumerate(zip(self._held, verified,
                                                                       strict=True))
                         if v is not None}
        out: list[tuple[str, Any]] = []
        keep: list[_Held] = []
        waiting: set[tuple[str, int, int]] = set()
        for i, (held, signed) in enumerate(zip(self._held, verified, strict=True)):
            if held.instance in waiting:
                keep.append(held)  # behind an earlier sample of its instance
            elif signed is not None:
                if self._in_order(signed, held.topic, held.sample):
                    out.append((held.topic, held.sample))
            elif newest_signed.get(held.instance, -1) > i:
                self.stats.superseded += 1
            elif self.enrolled(held.rid) is None:
                out.append((held.topic, held.sample))  # enrolment was withdrawn
            elif now >= self._deadline(held):
                self._reject_unsigned(held.rid, held.topic)
            else:
                keep.append(held)
                waiting.add(held.instance)
        self._held = keep
        counts: dict[tuple[str, int, int], int] = {}
        for held in keep:
            counts[held.instance] = counts.get(held.instance, 0) + 1
        self._held_per_instance = counts
        return out

    def _stamp(self, now: float) -> None:
        for rid in self._unstamped:
            self._signing[rid] = now
        self._unstamped.clear()

    def _deadline(self, held: _Held) -> float:
        """When ``held`` is rejected unsigned: :data:`SIGNATURE_WAIT` after it came or after
        its robot's first signature, whichever is later; :data:`FIRST_SIGNATURE_WAIT` after
        it came while no signature of its robot has come yet."""
        since = self._signing.get(held.rid)
        if since is None:
            return held.arrived + FIRST_SIGNATURE_WAIT
        return max(held.arrived, since) + self.wait

    @property
    def holding(self) -> int:
        return len(self._held)

    def _in_order(self, signed: SignedSample, topic: str, sample: Any) -> bool:
        source = _source(sample)
        if signed.topic != topic or signed.source != source:
            # a valid signature of other bytes: only a forger moves one
            self.stats.forged += 1
            self.on_problem(signed.robot_id, "forged", f"{signed.robot_id}: a signature of "
                            f"{signed.topic} was presented for {topic}; not shown")
            return False
        instance = (topic, *source)
        last = self._last.get(instance)
        shown = (int(source[0]), signed.digest)
        if last is not None and signed.order < last:
            if shown in self._shown:
                self.stats.replayed += 1
                self.on_problem(signed.robot_id, "replayed", f"{signed.robot_id}: an older "
                                f"signed {topic} sample was sent again after a newer one; "
                                "not shown")
            else:
                self.stats.superseded += 1
            return False
        self._shown[shown] = None
        while len(self._shown) > MAX_VERIFIED:
            self._shown.popitem(last=False)
        self._last[instance] = signed.order
        self._last.move_to_end(instance)
        while len(self._last) > MAX_INSTANCES:
            self._last.popitem(last=False)
        self.stats.verified += 1
        return True

    def _reject_unsigned(self, rid: int, topic: str) -> None:
        self.stats.unsigned += 1
        enrolled = self.enrolled(rid)
        robot_id = enrolled[0] if enrolled is not None else f"#{rid}"
        self.on_problem(robot_id, "unsigned", f"{robot_id}: a {topic} sample without the "
                        "robot's signature was rejected (forged, or its signature was lost)")

    def _note_key(self, rid: int, sig: C_Sample_Signature) -> None:
        """Trust on first use needs the key a robot signs with: noted once it verified its
        own signature and the robot id belongs to the resource id (else it is junk)."""
        if self.on_key_seen is None:
            return
        robot_id = sig.A_robotId
        key = public_key_of(sig)
        if key is None or len(robot_id) > 200 or robot_resource_id(robot_id) != rid:
            return
        raw = raw_public_key(key)
        if (robot_id, raw) in self._keys_seen:
            return
        if verify_sample_signature(key, robot_id, sig) is None:
            return
        if len(self._keys_seen) < 10_000:
            self._keys_seen.add((robot_id, raw))
        self.on_key_seen(robot_id, key)


@dataclass(slots=True)
class _Writer:
    participant: str
    last: float


class WriterWatch:
    """Notices two DDS participants writing under one robot's resource id at once.

    A robot restart brings a new participant after the old one left the domain; a second
    writer is one whose samples arrive while another participant that wrote for the same
    robot within :data:`WRITER_OVERLAP` seconds is still on the domain."""

    def __init__(self) -> None:
        self._writers: dict[int, list[_Writer]] = {}
        self.flagged: set[tuple[int, str]] = set()

    def saw(self, rid: int, participant: str, now: float,
            alive: Callable[[str], bool]) -> str | None:
        """Note a sample of ``rid`` from ``participant``; returns the other participant's
        key when this makes two writers (once per pair)."""
        writers = self._writers.setdefault(rid, [])
        other = None
        for w in writers:
            if w.participant == participant:
                w.last = now
                participant = ""
            elif now - w.last <= WRITER_OVERLAP and alive(w.participant):
                other = w.participant
        if participant:
            writers.append(_Writer(participant, now))
            del writers[:-4]  # bounded: the newest few writers per robot
            if other is not None and (rid, participant) not in self.flagged:
                self.flagged.add((rid, participant))
                return other
        return None
