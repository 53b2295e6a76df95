"""Robot health the robot signed: per-sample signatures and signed replies.

Anyone on a DDS domain can write a UCMS sample under any robot's source ids; the bytes
cannot say who wrote them. So each black box owns an Ed25519 key (``blackbox keygen``)
and signs what it publishes, without changing a UCMS type (plain UCMS readers keep
working and never see a signature):

* **Health samples** (entities, characteristics, thresholds, events and their extensions):
  before writing a sample the robot writes a :class:`C_Sample_Signature` on the extension
  topic ``BlackBox_Sample_Signature``, keyed by the sample's topic and source id (durable,
  like the state it signs, so a late-joining station gets both). It signs
  :func:`sample_message`: the robot id, topic, source id, the robot's boot id and a counter
  (1, 2, ... per boot), the signing time and SHA-256 of the sample's CDR encoding (the exact
  bytes on the wire: a station re-encodes what it received and gets the same digest).
* **Replies** (log reply chunks, IBIT results; black-box types, not UCMS) carry the
  signature in their own ``A_robotSignature`` field, over the reply's encoding with that
  field empty (:func:`seal`). A reply names the station's request id or reference number,
  which the station chose at random, so an old reply cannot answer a new request.

The station side (``blackbox.station.trust``) verifies with the key it enrolled for the
robot. Per-sample signing costs one Ed25519 signature per sample (measured in
docs/health.md, "Authenticated health").
"""

from __future__ import annotations

import copy
import hashlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from blackbox.health.extension import C_Sample_Signature
from blackbox.health.identity import new_boot
from blackbox.health.types import T_IdentifierType

SAMPLE_VERSION = "blackbox-sample-v1"
REPLY_VERSION = "blackbox-reply-v1"
SIGNATURE_TOPIC = "BlackBox_Sample_Signature"
MAX_SIGNATURE = 64
MAX_KEY = 32


def digest(sample: Any) -> bytes:
    """SHA-256 of the sample's CDR encoding (what the writer put on the wire)."""
    return hashlib.sha256(sample.serialize()).digest()


def raw_public_key(key: Ed25519PublicKey) -> bytes:
    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def sample_message(robot_id: str, topic: str, source: T_IdentifierType, boot: str,
                   counter: int, signed_ns: int, sample_digest: bytes) -> bytes:
    """The bytes a sample signature covers; every field is fixed-format, so signer and
    verifier cannot disagree on an encoding."""
    head = (f"{SAMPLE_VERSION}\n{robot_id}\n{topic}\n{int(source.A_resourceId)}:"
            f"{int(source.A_instanceId)}\n{boot}\n{int(counter)}\n{int(signed_ns)}\n")
    return head.encode("utf-8") + bytes(sample_digest)


def reply_message(robot_id: str, topic: str, reply: Any) -> bytes:
    """The bytes a reply signature covers: the reply encoded with no signature in it."""
    bare = copy.copy(reply)
    bare.A_robotSignature = []
    return f"{REPLY_VERSION}\n{robot_id}\n{topic}\n".encode() + digest(bare)


@dataclass(frozen=True, slots=True)
class SignedSample:
    """What a verified sample signature says: which sample (topic, source id, digest) the
    robot published, in which boot, as which number and when."""

    robot_id: str
    topic: str
    source: tuple[int, int]
    boot: str
    counter: int
    signed_ns: int
    digest: bytes

    @property
    def order(self) -> tuple[int, int]:
        """Newer signatures compare greater (the counter breaks ties within a boot)."""
        return (self.signed_ns, self.counter)


class SampleSigner:
    """Signs one robot's samples and replies; thread-safe (the pipeline thread publishes
    while the service thread answers requests)."""

    def __init__(self, key: Ed25519PrivateKey, robot_id: str, *, boot: str | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        self.key = key
        self.robot_id = robot_id
        self.boot = boot or new_boot()
        self.clock = clock
        self.public_key = raw_public_key(key.public_key())
        self._counter = 0
        self._lock = threading.Lock()
        self.signed = 0

    def sign(self, topic: str, sample: Any) -> C_Sample_Signature:
        """The signature sample to write (first) for ``sample`` on ``topic``."""
        source: T_IdentifierType = sample.A_sourceID
        sample_digest = digest(sample)
        with self._lock:
            self._counter += 1
            counter = self._counter
            signed_ns = int(self.clock() * 1e9)
            self.signed += 1
        message = sample_message(self.robot_id, topic, source, self.boot, counter, signed_ns,
                                 sample_digest)
        return C_Sample_Signature(
            A_sourceID=T_IdentifierType(int(source.A_resourceId), int(source.A_instanceId)),
            A_topic=topic, A_robotId=self.robot_id, A_boot=self.boot, A_counter=counter,
            A_signedNs=signed_ns, A_digest=list(sample_digest),
            A_publicKey=list(self.public_key), A_signature=list(self.key.sign(message)))

    def seal(self, topic: str, reply: Any) -> Any:
        """``reply`` with its ``A_robotSignature`` set (changed in place and returned)."""
        reply.A_robotSignature = list(self.key.sign(reply_message(self.robot_id, topic,
                                                                  reply)))
        return reply


def verify_sample_signature(key: Ed25519PublicKey, robot_id: str,
                            signature: C_Sample_Signature) -> SignedSample | None:
    """The signed facts if ``signature`` is ``robot_id``'s with ``key``, else ``None``.
    Bounded: oversized fields are refused before any cryptography runs."""
    sig = bytes(signature.A_signature[:MAX_SIGNATURE + 1])
    sample_digest = bytes(signature.A_digest[:33])
    if (len(sig) != MAX_SIGNATURE or len(sample_digest) != 32 or signature.A_robotId != robot_id
            or len(signature.A_topic) > 64 or len(signature.A_boot) > 32):
        return None
    message = sample_message(robot_id, signature.A_topic, signature.A_sourceID,
                             signature.A_boot, int(signature.A_counter),
                             int(signature.A_signedNs), sample_digest)
    try:
        key.verify(sig, message)
    except (InvalidSignature, ValueError):
        return None
    return SignedSample(robot_id, signature.A_topic,
                        (int(signature.A_sourceID.A_resourceId),
                         int(signature.A_sourceID.A_instanceId)),
                        signature.A_boot, int(signature.A_counter), int(signature.A_signedNs),
                        sample_digest)


def reply_signed_by(key: Ed25519PublicKey, robot_id: str, topic: str, reply: Any) -> bool:
    """Whether ``reply`` carries ``robot_id``'s valid signature made with ``key``."""
    sig = bytes(reply.A_robotSignature[:MAX_SIGNATURE + 1])
    if len(sig) != MAX_SIGNATURE:
        return False
    try:
        key.verify(sig, reply_message(robot_id, topic, reply))
    except (InvalidSignature, ValueError):
        return False
    return True


def public_key_of(signature: C_Sample_Signature) -> Ed25519PublicKey | None:
    """The key a signature sample says it was made with (for trust on first use)."""
    raw = bytes(signature.A_publicKey[:MAX_KEY + 1])
    if len(raw) != MAX_KEY:
        return None
    try:
        return Ed25519PublicKey.from_public_bytes(raw)
    except ValueError:
        return None
