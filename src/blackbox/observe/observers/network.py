"""Receive and transmit rates of one network interface, in bytes per second.

Samples carry cumulative counters; a rate is the counter difference between consecutive
samples over their time difference. A counter that goes down (interface reset, driver
reload, wrap-around) gives no rate for that pair: the next pair starts from the new value.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

from blackbox.config.node import ConfigNode
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import OBSERVERS, ObserverBase, register
from blackbox.observe.observers.entry import COMMON_KEYS, read_every, read_name, read_quantity
from blackbox.observe.observers.quantity import (
    FilteredQuantity,
    byte_count,
    describe_states_inline,
    judge,
)
from blackbox.observe.states import StateSpec, parse_states
from blackbox.sources.base import Interest, NetworkSample


class NetworkObserver(ObserverBase):
    """Traffic rates of one network interface."""

    type_name: ClassVar[str] = "network"

    def __init__(self, interface: str, rx: FilteredQuantity, tx: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        self.interface = interface
        self.rx = rx
        self.tx = tx
        self.states = tuple(states)
        self.interval = every
        self.resource = Resource(interface=interface)
        self._previous: NetworkSample | None = None

    def interest(self) -> Interest:
        return Interest(network=True)

    def on_network(self, sample: NetworkSample) -> None:
        if sample.interface != self.interface:
            return
        previous = self._previous
        if previous is not None and sample.time <= previous.time:
            return
        self._previous = sample
        if previous is None:
            return
        d_rx = sample.rx_bytes - previous.rx_bytes
        d_tx = sample.tx_bytes - previous.tx_bytes
        if d_rx < 0 or d_tx < 0:
            return
        dt = sample.time - previous.time
        self.rx.update(d_rx / dt)
        self.tx.update(d_tx / dt)

    def evaluate(self, now: float) -> list[Observation]:
        rx, tx = self.rx.summary(), self.tx.summary()
        if rx is None or tx is None:
            why = ("waiting for the first sample" if self._previous is None
                   else "waiting for a second sample (rates need two)")
            return [Observation(now, self.type_name, self.resource, Code.NOT_AVAILABLE,
                                message=f"{why} of interface {self.interface}")]
        verdict = judge(self.states, {"rx": rx, "tx": tx})
        message = (f"rx {byte_count(rx.value)}/s, tx {byte_count(tx.value)}/s "
                   f"{verdict.fits}")
        return [Observation(now, self.type_name, self.resource, verdict.code, verdict.states,
                            verdict.values, message)]

    def describe(self) -> str:
        return (f"network {self.interface}: {self.rx.describe()}, {self.tx.describe()}; "
                f"{describe_states_inline(self.states)}, every {self.interval:g} s")


@register(OBSERVERS, "network")
def network_from_config(node: ConfigNode) -> NetworkObserver:
    node.check_keys((*COMMON_KEYS, "interface", "rx_filter", "tx_filter", "states"))
    return NetworkObserver(
        interface=read_name(node, "interface"),
        rx=read_quantity(node, "rx_filter", "rx"),
        tx=read_quantity(node, "tx_filter", "tx"),
        states=parse_states(node.get("states"), ("rx", "tx")),
        every=read_every(node),
    )
