"""CPU (percent of one core) and memory (bytes) of one node, each through its own filter.

A sample without a value (the process is gone, or not readable) is never a silent zero:
the observation is ``NOT_AVAILABLE`` with the sample's reason until a complete sample
arrives. The present value of an incomplete sample is still filtered.

Measurement gaps: samples stamped inside a gap of the node (or of everything) are skipped,
and while one is open the observation is ``NOT_AVAILABLE`` ("not measured since ...");
a paused black box samples late, not wrongly, so nothing else changes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MeasurementGap, ResourceSample
from blackbox.model import Observation, Resource
from blackbox.observe.base import OBSERVERS, ObserverKind, Quantity, Subject
from blackbox.observe.gaps import Unmeasured
from blackbox.observe.observers.entry import COMMON_KEYS, read_judged, read_name
from blackbox.observe.observers.quantity import FilteredQuantity, JudgedObserver, byte_count
from blackbox.observe.states import StateSpec


class ResourcesObserver(JudgedObserver):
    """CPU and memory use of one node."""

    type_name: ClassVar[str] = "resources"

    def __init__(self, node: str, cpu: FilteredQuantity, memory: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        super().__init__(Resource(node=node), (cpu, memory), states, every)
        self.node = node
        self.cpu = cpu
        self.memory = memory
        self._latest: ResourceSample | None = None
        self._gaps = Unmeasured()

    def interest(self) -> Interest:
        return Interest(resources=frozenset({self.node}))

    def on_resources(self, sample: ResourceSample) -> None:
        if sample.node != self.node or self._gaps.covers(sample.time):
            return
        self._latest = sample
        if sample.cpu_percent is not None:
            self.cpu.update(sample.cpu_percent)
        if sample.memory_bytes is not None:
            self.memory.update(sample.memory_bytes)

    def on_gap(self, gap: MeasurementGap) -> None:
        self._gaps.apply(gap)

    def evaluate(self, now: float) -> list[Observation]:
        unmeasured = self._gaps.observation(now, self.type_name, self.resource)
        if unmeasured is not None:
            return [unmeasured]
        latest = self._latest
        if latest is None:
            return [self.unavailable(now, f"waiting for the first resource sample of "
                                          f"{self.node}")]
        if latest.cpu_percent is None or latest.memory_bytes is None:
            missing = " and ".join(name for name, v in (("cpu", latest.cpu_percent),
                                                         ("memory", latest.memory_bytes))
                                   if v is None)
            reason = latest.reason or "no reason given"
            return [self.unavailable(now, f"no {missing} value for {self.node}: {reason}")]
        cpu, memory = self.cpu.summary(), self.memory.summary()
        if cpu is None or memory is None:  # only after non-finite samples were rejected
            return [self.unavailable(now, f"no valid resource sample of {self.node} yet")]
        return [self.judged(now, {"cpu": cpu, "memory": memory},
                            f"cpu {cpu.value:.3g} %, memory {byte_count(memory.value)}")]

    def subject(self) -> str:
        return self.node


def resources_from_config(node: ConfigNode) -> ResourcesObserver:
    node.check_keys((*COMMON_KEYS, "node", "cpu_filter", "memory_filter", "states"))
    name = read_name(node, "node")
    judged = read_judged(node, {"cpu_filter": "cpu", "memory_filter": "memory"})
    q = judged.quantities
    return ResourcesObserver(name, q["cpu"], q["memory"], judged.states, judged.every)


def resources_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    group.check_keys(["type", "main_loop_rate", "nodes", *tug.IGNORED])
    every = tug.every(group)
    for node in group["nodes"].list():
        node.check_keys(["name", "cpu_filter", "mem_filter", "states"])
        out.entries.append(tug.entry(
            "resources", node, node=node["name"], every=every,
            cpu_filter=tug.filter_entry(tug.child(node, "cpu_filter")),
            memory_filter=tug.filter_entry(tug.child(node, "mem_filter")),
            states=tug.states(tug.child(node, "states"), {"cpu": "cpu", "memory": "memory"})))


OBSERVERS.add("resources", ObserverKind(
    "resources", resources_from_config, Subject.NODE,
    (Quantity("cpu", "%"), Quantity("memory", "B")), tug=resources_from_tug, logged_values=4),
    example={"type": "resources", "node": "/camera",
             "cpu_filter": {"type": "mean", "window_size": 3},
             "states": [{"number": 1, "name": "ok",
                         "cpu": {"value": {"type": "less_than", "less_than": 90.0}}}]})
