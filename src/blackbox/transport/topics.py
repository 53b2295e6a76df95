"""Every topic the black box and the station use, by name, and its IDL type: UCMS, the
black box's extensions, the remote interface. Shared by both buses (DDS and Zenoh)."""

from __future__ import annotations

from blackbox.health.extension import EXTENSION_TOPICS
from blackbox.health.types import REMOTE_TOPICS, UCMS_TOPICS

ALL_TOPICS: dict[str, type] = {**UCMS_TOPICS, **EXTENSION_TOPICS, **REMOTE_TOPICS}
TOPIC_OF_TYPE: dict[type, str] = {t: name for name, t in ALL_TOPICS.items()}
