"""The diagnosis stage of a running black box.

Without a model file the robot model is derived from the live graph, so a robot needs no
extra configuration; when nodes or topics appear or vanish at run time the model is derived
again and the latest observations are replayed into it. With a tug_diagnosis model file the
model is fixed.

Configured by the native ``diagnosis:`` section::

    diagnosis:
      enabled: true             # default
      model: robot_model.yaml   # optional tug_diagnosis file, relative to the config file
      priors: {/usb_cam: 0.2, topic: 0.005}   # component names or kinds -> probability
      max_cardinality: 4        # largest diagnosis searched
      time_budget: 0.1          # CPU seconds per re-diagnosis (anytime: best so far)
      engine: cbd               # cbd | sfdd | hybrid (docs/diagnosis.md, "SFDD")
      sfdd: {signals: [...]}    # SFDD's signals and settings (diagnose/sfdd_live.py)
      hybrid: rank              # rank | verify: may SFDD withhold a CBD value alarm?
      propagation:              # how an input's fault reaches a node's outputs
        rate: learn             # learn | always | never: does a silent input silence the node?
        learn_after: 3.0        # seconds of "input silent, output at rate" before learning never
        value_from_rate: false  # may a silent or off-rate input make the node's values wrong?
        nodes:                  # per-node overrides of rate and value_from_rate
          /Signal_generator: {rate: never}

``propagation.rate``: ``always`` means a node stops publishing when an input falls silent,
so the input's silence explains the node's; ``never`` means it publishes on its own clock;
``learn`` (default) assumes ``always`` until the node is seen publishing at rate while the
input is silent for ``learn_after`` seconds. A value failure of an output is explained by
an input only through a value failure of that input, unless ``value_from_rate`` is true.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from blackbox.config.node import ConfigNode
from blackbox.diagnose.engine import DiagnosisEngine
from blackbox.diagnose.robot_model import (
    RATE_MODES,
    NodePropagation,
    ObservedResource,
    Propagation,
)
from blackbox.diagnose.sfdd_live import SfddConfig
from blackbox.events import GraphSnapshot
from blackbox.model import Diagnosis, Observation, Resource
from blackbox.observe.base import JudgedSignals, SignalJudge


@dataclass(frozen=True)
class DiagnosisSettings:
    enabled: bool = True
    model: Path | None = None
    priors: Mapping[str, float] = field(default_factory=dict)
    max_cardinality: int | None = 4
    time_budget: float = 0.1
    propagation: Propagation = field(default_factory=Propagation)
    engine: str = "cbd"
    sfdd: SfddConfig = field(default_factory=SfddConfig)
    hybrid: str = "rank"

    @classmethod
    def from_config(cls, node: ConfigNode | None, base_dir: Path) -> DiagnosisSettings:
        if node is None:
            return cls()
        node.check_keys(["enabled", "model", "priors", "max_cardinality", "time_budget",
                         "propagation", "engine", "sfdd", "hybrid"])
        enabled = node["enabled"].bool() if node.get("enabled") is not None else True
        model = None
        if node.get("model") is not None:
            model = Path(node["model"].str())
            model = model if model.is_absolute() else base_dir / model
            if not model.is_file():
                raise node["model"].error(f"diagnosis model {model} not found")
        priors: dict[str, float] = {}
        if node.get("priors") is not None:
            for name, value in node["priors"].items():
                priors[name] = value.float(min=0.0, min_exclusive=True, max=0.999999)
        max_card = (node["max_cardinality"].int(min=1) if node.get("max_cardinality")
                    is not None else 4)
        budget = (node["time_budget"].float(min=0.0, min_exclusive=True)
                  if node.get("time_budget") is not None else 0.1)
        propagation = (_propagation(node["propagation"]) if node.get("propagation")
                       is not None else Propagation())
        engine = (node["engine"].str(["cbd", "sfdd", "hybrid"]) if node.get("engine")
                  is not None else "cbd")
        sfdd = SfddConfig.from_config(node.get("sfdd"))
        if engine != "cbd" and len(sfdd.signals) < 2:
            raise node["engine"].error(f"engine {engine} needs diagnosis.sfdd.signals: two or "
                                       "more numeric fields of topics")
        hybrid = (node["hybrid"].str(["rank", "verify"]) if node.get("hybrid") is not None
                  else "rank")
        return cls(enabled, model, priors, max_card, budget, propagation, engine, sfdd, hybrid)


def _modes(node: ConfigNode) -> NodePropagation:
    """``rate`` and ``value_from_rate`` of a ``propagation`` section or one of its nodes."""
    rate = node["rate"].str(RATE_MODES) if node.get("rate") is not None else None
    stale = node["value_from_rate"].bool() if node.get("value_from_rate") is not None else None
    return NodePropagation(rate, stale)


def _propagation(node: ConfigNode) -> Propagation:
    node.check_keys(["rate", "value_from_rate", "learn_after", "nodes"])
    default = Propagation()
    own = _modes(node)
    learn_after = (node["learn_after"].float(min=0.0) if node.get("learn_after") is not None
                   else default.learn_after)
    nodes: dict[str, NodePropagation] = {}
    if node.get("nodes") is not None:
        for name, item in node["nodes"].items():
            item.check_keys(["rate", "value_from_rate"])
            nodes[name] = _modes(item)
    return Propagation(
        default.rate if own.rate is None else own.rate,
        default.value_from_rate if own.value_from_rate is None else own.value_from_rate,
        learn_after, nodes)


def judged_signals(observers: Sequence[ObservedResource]
                   ) -> dict[tuple[str, Resource], JudgedSignals]:
    """The fields each relation observer sees, by observation key: the engine accuses and
    clears those fields, not the observers' topics as a whole."""
    return {(o.type_name, o.resource): o.judged_signals() for o in observers
            if isinstance(o, SignalJudge)}


def _structure(graph: GraphSnapshot) -> frozenset[tuple[str, tuple[str, ...], tuple[str, ...]]]:
    return frozenset((t.name, tuple(sorted(t.publishers)), tuple(sorted(t.subscribers)))
                     for t in graph.topics.values())


class LiveDiagnoser:
    """A :class:`DiagnosisEngine` that follows the robot's graph."""

    def __init__(self, observers: Sequence[ObservedResource], settings: DiagnosisSettings
                 ) -> None:
        self.observers = list(observers)
        self.settings = settings
        self.engine: DiagnosisEngine | None = None
        self._structure: frozenset[tuple[str, tuple[str, ...], tuple[str, ...]]] | None = None
        self._latest: dict[tuple[str, object], Observation] = {}
        if settings.model is not None:
            self.engine = DiagnosisEngine.from_model_file(settings.model, settings.priors,
                                                          **self._engine_kwargs())

    def _engine_kwargs(self) -> dict[str, object]:
        kwargs: dict[str, object] = {"max_cardinality": self.settings.max_cardinality,
                                     "time_budget": self.settings.time_budget,
                                     "propagation": self.settings.propagation,
                                     "signals": judged_signals(self.observers)}
        if self.engine is not None:
            kwargs["independent"] = self.engine.independent
            kwargs["blamed"] = self.engine.blamed
        return kwargs

    def on_graph(self, graph: GraphSnapshot) -> None:
        if self.settings.model is not None:
            return
        structure = _structure(graph)
        if structure == self._structure:
            return
        self._structure = structure
        self.engine = DiagnosisEngine.from_graph(graph, self.observers, self.settings.priors,
                                                 **self._engine_kwargs())
        if self._latest:
            self.engine.update(graph.time, list(self._latest.values()))

    def replace_observers(self, observers: Sequence[ObservedResource],
                          graph: GraphSnapshot | None) -> None:
        """New observers (an imported configuration): derive the model again."""
        self.observers = list(observers)
        self._latest.clear()
        self._structure = None
        if graph is not None:
            self.on_graph(graph)

    def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None:
        for obs in observations:
            self._latest[obs.key()] = obs
        if self.engine is None:
            return None
        return self.engine.update(now, observations)
