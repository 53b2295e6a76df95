"""CPU (percent of one core) and memory (bytes) of one node, each through its own filter.

A sample without a value (the process is gone, or not readable) is never a silent zero:
the observation is ``NOT_AVAILABLE`` with the sample's reason until a complete sample
arrives. The present value of an incomplete sample is still filtered.
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
from blackbox.sources.base import Interest, ResourceSample


class ResourcesObserver(ObserverBase):
    """CPU and memory use of one node."""

    type_name: ClassVar[str] = "resources"

    def __init__(self, node: str, cpu: FilteredQuantity, memory: FilteredQuantity,
                 states: Sequence[StateSpec] = (), every: float = 1.0) -> None:
        self.node = node
        self.cpu = cpu
        self.memory = memory
        self.states = tuple(states)
        self.interval = every
        self.resource = Resource(node=node)
        self._latest: ResourceSample | None = None

    def interest(self) -> Interest:
        return Interest(resources=frozenset({self.node}))

    def on_resources(self, sample: ResourceSample) -> None:
        if sample.node != self.node:
            return
        self._latest = sample
        if sample.cpu_percent is not None:
            self.cpu.update(sample.cpu_percent)
        if sample.memory_bytes is not None:
            self.memory.update(sample.memory_bytes)

    def evaluate(self, now: float) -> list[Observation]:
        latest = self._latest
        if latest is None:
            return [self._unavailable(now, f"waiting for the first resource sample of "
                                           f"{self.node}")]
        if latest.cpu_percent is None or latest.memory_bytes is None:
            missing = " and ".join(name for name, v in (("cpu", latest.cpu_percent),
                                                         ("memory", latest.memory_bytes))
                                   if v is None)
            reason = latest.reason or "no reason given"
            return [self._unavailable(now, f"no {missing} value for {self.node}: {reason}")]
        cpu, memory = self.cpu.summary(), self.memory.summary()
        if cpu is None or memory is None:  # only after non-finite samples were rejected
            return [self._unavailable(now, f"no valid resource sample of {self.node} yet")]
        verdict = judge(self.states, {"cpu": cpu, "memory": memory})
        message = f"cpu {cpu.value:.3g} %, memory {byte_count(memory.value)} {verdict.fits}"
        return [Observation(now, self.type_name, self.resource, verdict.code, verdict.states,
                            verdict.values, message)]

    def _unavailable(self, now: float, why: str) -> Observation:
        return Observation(now, self.type_name, self.resource, Code.NOT_AVAILABLE, message=why)

    def describe(self) -> str:
        return (f"resources {self.node}: {self.cpu.describe()}, {self.memory.describe()}; "
                f"{describe_states_inline(self.states)}, every {self.interval:g} s")


@register(OBSERVERS, "resources")
def resources_from_config(node: ConfigNode) -> ResourcesObserver:
    node.check_keys((*COMMON_KEYS, "node", "cpu_filter", "memory_filter", "states"))
    return ResourcesObserver(
        node=read_name(node, "node"),
        cpu=read_quantity(node, "cpu_filter", "cpu"),
        memory=read_quantity(node, "memory_filter", "memory"),
        states=parse_states(node.get("states"), ("cpu", "memory")),
        every=read_every(node),
    )
