"""Reading the keys every observer entry shares, with one clear error per mistake, and
saying a publisher group back in ``describe()``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from blackbox.config.node import ConfigNode
from blackbox.model import Resource
from blackbox.observe.filters import build_filter
from blackbox.observe.observers.quantity import FilteredQuantity
from blackbox.observe.states import StateSpec, parse_states

COMMON_KEYS: tuple[str, ...] = ("type", "every")
DEFAULT_EVERY = 1.0


def read_every(node: ConfigNode) -> float:
    """``every``: seconds between evaluations, > 0 (default 1.0)."""
    child = node.get("every")
    return DEFAULT_EVERY if child is None else child.float(min=0.0, min_exclusive=True)


def read_name(node: ConfigNode, key: str) -> str:
    """A required topic, node or interface name."""
    child = node[key]
    if child.is_null:
        raise child.error(f"{key} must be a name, got nothing (null)")
    name = child.str()
    if name != name.strip() or not name.strip():
        raise child.error(f"{key} {name!r} has leading or trailing blanks")
    return name


def read_publishers(node: ConfigNode, key: str = "publishers") -> tuple[str, ...]:
    """A publisher group: a list of node names; absent or empty means all publishers."""
    child = node.get(key)
    if child is None:
        return ()
    names = child.str_list()
    if len(set(names)) != len(names):
        raise child.error(f"{key} lists a publisher twice")
    return names


def describe_publishers(publishers: tuple[str, ...]) -> str:
    """A publisher group as ``describe()`` shows it."""
    return ",".join(publishers) if publishers else "all publishers"


def read_bool(node: ConfigNode, key: str, default: bool) -> bool:
    child = node.get(key)
    return default if child is None else child.bool()


def read_quantity(node: ConfigNode, filter_key: str, name: str) -> FilteredQuantity:
    """The quantity ``name`` observed through the filter at ``filter_key`` (absent: none)."""
    return FilteredQuantity(name, build_filter(node.get(filter_key)))


@dataclass(frozen=True, slots=True)
class PublisherGroup:
    """A topic and the publishers whose messages count there; no publishers means all."""

    topic: str
    publishers: tuple[str, ...] = ()

    @property
    def members(self) -> frozenset[str]:
        return frozenset(self.publishers)

    @property
    def resource(self) -> Resource:
        return Resource(topic=self.topic, publishers=self.publishers)

    def describe(self) -> str:
        return f"{self.topic} [{describe_publishers(self.publishers)}]"


def read_filtered_group(node: ConfigNode, quantity: str) -> tuple[PublisherGroup, Judged]:
    """An entry of one publisher group on one topic, one filtered ``quantity`` and states."""
    node.check_keys((*COMMON_KEYS, "topic", "publishers", "filter", "states"))
    return read_group(node), read_judged(node, {"filter": quantity})


def read_group(node: ConfigNode, topic_key: str = "topic",
               publishers_key: str = "publishers") -> PublisherGroup:
    return PublisherGroup(read_name(node, topic_key), read_publishers(node, publishers_key))


@dataclass(frozen=True, slots=True)
class Judged:
    """The filtered quantities, states and interval of an entry whose states judge it."""

    quantities: dict[str, FilteredQuantity]
    states: tuple[StateSpec, ...]
    every: float


def read_judged(node: ConfigNode, filters: Mapping[str, str]) -> Judged:
    """Each quantity ``filters[key]`` through the filter at ``key``, the states over them and
    ``every``."""
    quantities = {name: read_quantity(node, key, name) for key, name in filters.items()}
    states = parse_states(node.get("states"), tuple(filters.values()))
    return Judged(quantities, tuple(states), read_every(node))
