"""Characteristic values taken in a backlog, thinned to the newest of each characteristic.

A station that cannot keep up with its fleet for long (:class:`~blackbox.station.delivery.
DeliveryWatch` says it is behind) would otherwise let the bus's queue overflow, and the bus
drops the oldest samples of whatever topic overflows, failures and entity statuses
included, and holds every sample behind the backlog: a robot's fault reached the page
seconds late. Characteristic values are state: the newest value of a characteristic says
what an older one said about now. So while behind, the follower takes the whole backlog of
values and handles only the newest value of each characteristic; the older ones are
counted (``blackbox_station_values_coalesced_total``, a problem on the page), never
silently lost. Events and statuses are never coalesced.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def newest_per_characteristic(samples: Sequence[Any]) -> tuple[list[Any], int]:
    """The newest sample (the last taken) of each characteristic (``A_sourceID``: robot and
    instance) in taking order, and how many older ones were left out."""
    last: dict[tuple[int, int], int] = {}
    for i, sample in enumerate(samples):
        source = sample.A_sourceID
        last[(int(source.A_resourceId), int(source.A_instanceId))] = i
    keep = sorted(last.values())
    return [samples[i] for i in keep], len(samples) - len(keep)


__all__ = ["newest_per_characteristic"]
