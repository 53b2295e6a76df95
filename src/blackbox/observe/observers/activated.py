"""Whether a node is running, as the node itself answers (not what a registry remembers).

A node killed with SIGKILL stays registered in the ROS 1 master, so liveness comes from
``GraphSnapshot.nodes[node].alive``, which the source fills from the node's own API.
The verdict follows the latest snapshot at the next evaluation.

``start_up_time`` is grace for a robot still starting: within that many seconds of the
observer's first event (first snapshot or first evaluation, whichever comes first) a node
that is not running yet is ``NOT_AVAILABLE`` rather than an error. A running node is
``GENERAL_OK`` at once.

Measurement gaps of the node (or of everything): snapshots stamped inside one are not
used; while one is open, and after it until the first snapshot stamped after its end, the
observation is ``NOT_AVAILABLE``: a probe that timed out while the black box itself was
paused says nothing about the node.
"""

from __future__ import annotations

from typing import ClassVar

from blackbox.config import tug
from blackbox.config.node import ConfigNode
from blackbox.events import GraphSnapshot, Interest, MeasurementGap, NodeInfo
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import (
    OBSERVERS,
    FixedThreshold,
    ObserverBase,
    ObserverKind,
    Quantity,
    Subject,
)
from blackbox.observe.gaps import UNMEASURED, Unmeasured, moment
from blackbox.observe.observers.entry import COMMON_KEYS, read_every, read_name


class ActivatedObserver(ObserverBase):
    """Liveness of one node."""

    type_name: ClassVar[str] = "activated"

    def __init__(self, node: str, start_up_time: float = 0.0, every: float = 1.0) -> None:
        self.node = node
        self.start_up_time = start_up_time
        self.interval = every
        self.resource = Resource(node=node)
        self._started: float | None = None
        self._seen_graph = False
        self._info: NodeInfo | None = None
        self._gaps = Unmeasured()
        self._stale = False

    def interest(self) -> Interest:
        return Interest(nodes=frozenset({self.node}))

    def on_graph(self, graph: GraphSnapshot) -> None:
        if self._started is None:
            self._started = graph.time
        if self._gaps.covers(graph.time):
            return
        self._stale = False
        self._seen_graph = True
        self._info = graph.nodes.get(self.node)

    def on_gap(self, gap: MeasurementGap) -> None:
        if self._gaps.apply(gap):
            self._stale = True

    def evaluate(self, now: float) -> list[Observation]:
        if self._started is None:
            self._started = now
        unmeasured = self._gaps.observation(now, self.type_name, self.resource)
        if unmeasured is not None:
            return [unmeasured]
        if self._stale:
            return [Observation(
                now, self.type_name, self.resource, Code.NOT_AVAILABLE,
                values={UNMEASURED: self._gaps.last_start},
                message=f"not measured until {moment(self._gaps.ended)} "
                        f"({self._gaps.reason}); waiting for a graph snapshot after that")]
        info = self._info
        if not self._seen_graph:
            return [self._observation(now, Code.NOT_AVAILABLE,
                                      "waiting for the first graph snapshot")]
        if info is not None and info.alive:
            pid = f" (pid {info.pid})" if info.pid is not None else ""
            return [self._observation(now, Code.GENERAL_OK, f"node {self.node} is running{pid}",
                                      alive=1.0)]
        why = "not in the graph" if info is None else "registered but not answering"
        since_start = now - self._started
        if since_start < self.start_up_time:
            return [self._observation(
                now, Code.NOT_AVAILABLE,
                f"node {self.node} is not running yet ({why}); start-up time "
                f"{self.start_up_time:g} s, {since_start:.3g} s passed", alive=0.0)]
        return [self._observation(now, Code.GENERAL_ERROR,
                                  f"node {self.node} is not running ({why})", alive=0.0)]

    def _observation(self, now: float, code: Code, message: str,
                     alive: float | None = None) -> Observation:
        values = {} if alive is None else {"alive": alive}
        return Observation(now, self.type_name, self.resource, code, values=values,
                           message=message)

    def describe(self) -> str:
        grace = f", start-up time {self.start_up_time:g} s" if self.start_up_time else ""
        return f"activated {self.node}: node alive{grace}, every {self.interval:g} s"


def activated_from_config(node: ConfigNode) -> ActivatedObserver:
    node.check_keys((*COMMON_KEYS, "node", "start_up_time"))
    start_up = node.get("start_up_time")
    return ActivatedObserver(
        node=read_name(node, "node"),
        start_up_time=0.0 if start_up is None else start_up.float(min=0.0),
        every=read_every(node),
    )


def activated_from_tug(group: ConfigNode, out: tug.TugTranslation) -> None:
    group.check_keys(["type", "main_loop_rate", "start_up_time", "nodes", *tug.IGNORED])
    every = tug.every(group)
    start_up = group.get("start_up_time")
    for node in group["nodes"].list():
        node.check_keys(["name"])
        out.entries.append(tug.entry("activated", node, node=node["name"],
                                     start_up_time=start_up, every=every))


OBSERVERS.add("activated", ObserverKind(
    "activated", activated_from_config, Subject.NODE, (Quantity("code"),),
    thresholds=(FixedThreshold("code", "min", 0.0),), tug=activated_from_tug,
    failure_means_silent=True, logged_values=0),
    example={"type": "activated", "node": "/camera", "start_up_time": 1.0})
