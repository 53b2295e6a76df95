"""Receive and transmit rates of one network interface, in bytes per second.

Samples carry cumulative counters; a rate is the counter difference between consecutive
samples over their time difference. A counter that goes down (interface reset, driver
reload, wrap-around) gives no rate for that pair: the next pair starts from the new value.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

from blackbox.config.node import ConfigNode
from blackbox.events import Interest, NetworkSample
from blackbox.model import Observation, Resource
from blackbox.observe.base import OBSERVERS, ObserverKind, Quantity, Subject
from blackbox.observe.observers.entry import COMMON_KEYS, read_judged, read_name
from blackbox.observe.observers.quantity import FilteredQuantity, JudgedObserver, byte_count
from blackbox.observe.states import StateSpec


class NetworkObserver(JudgedObserver):
    """Traffic rates of one network interface."""

    type_name: ClassVar[str] = "network"

    def __init__(self, interface: str, rx: FilteredQuantity, tx: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        super().__init__(Resource(interface=interface), (rx, tx), states, every)
        self.interface = interface
        self.rx = rx
        self.tx = tx
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
            return [self.unavailable(now, f"{why} of interface {self.interface}")]
        return [self.judged(now, {"rx": rx, "tx": tx},
                            f"rx {byte_count(rx.value)}/s, tx {byte_count(tx.value)}/s")]

    def subject(self) -> str:
        return self.interface


def network_from_config(node: ConfigNode) -> NetworkObserver:
    node.check_keys((*COMMON_KEYS, "interface", "rx_filter", "tx_filter", "states"))
    interface = read_name(node, "interface")
    judged = read_judged(node, {"rx_filter": "rx", "tx_filter": "tx"})
    q = judged.quantities
    return NetworkObserver(interface, q["rx"], q["tx"], judged.states, judged.every)


OBSERVERS.add("network", ObserverKind(
    "network", network_from_config, Subject.INTERFACE,
    (Quantity("rx", "B/s"), Quantity("tx", "B/s")), logged_values=4),
    example={"type": "network", "interface": "eth0",
             "rx_filter": {"type": "mean", "window_size": 2},
             "states": [{"number": 1, "name": "ok",
                         "rx": {"value": {"type": "less_than", "less_than": 1e9}}}]})
