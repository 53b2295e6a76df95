"""SFDD on a running black box: signals tapped from topics, judged windows, component verdicts.

Configured under ``diagnosis:`` (docs/diagnosis.md, "SFDD")::

    diagnosis:
      engine: sfdd              # cbd (default) | sfdd | hybrid
      sfdd:
        period: 0.1             # seconds between samples of the common clock
        window: 100             # samples per window (10 s), first half for correlation
        stale_after: 1.0        # a signal without a message for this long is silent
        persistence: 1          # windows in a row a fault pattern must last to be reported
        signals:
          - {topic: /odom, field: twist.twist.linear.x}
          - {topic: /imu/data, field: angular_velocity.z, component: /imu_hardware}

:class:`SfddTap` is an observer: it samples every signal on one clock (the last value held,
as a sensor reading is held), judges the window once per ``interval`` with
:class:`~blackbox.diagnose.sfdd.SfddDetector` and reports one observation per signal
(observer ``sfdd:FIELD`` on the signal's topic), so the recorder, the UCMS mapping and the
station show SFDD's verdicts like any observer's. :class:`SfddDiagnoser` turns the faulty
signals into a diagnosis with the structural model (thesis 4.2): a signal belongs to its
``component`` (default: the topic's publisher node); when every signal of a component with
two or more signals is faulty the component is named, otherwise the faulty sensors (their
topics) are.

Bad input: a value that is NaN or infinite is dropped and counted (``non_finite`` in the
observation's values), so the held value ages and the signal falls silent after
``stale_after``; a silent or not-yet-started signal is NaN in the window and unjudged
(``NOT_AVAILABLE``) until a full window of fresh samples exists, because a silent topic
carries no values (the CBD engine's rule too: its rate observers see silence).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from blackbox.config.node import ConfigNode
from blackbox.diagnose.sfdd import SfddDetector, SfddSettings, SignalVerdict
from blackbox.events import GraphSnapshot, Interest, MessageArrival
from blackbox.model import Code, Diagnosis, Observation, Resource
from blackbox.observe.base import ObserverBase
from blackbox.observe.fieldpath import compile_field_path

OBSERVER_PREFIX = "sfdd:"


@dataclass(frozen=True, slots=True)
class SignalSpec:
    """One one-dimensional signal: a numeric field of a topic, and the component it
    belongs to in the structural model (``None``: the topic's publisher node)."""

    topic: str
    field: str = "data"
    component: str | None = None

    @property
    def name(self) -> str:
        return f"{self.topic}.{self.field}"


@dataclass(frozen=True)
class SfddConfig:
    """The ``diagnosis.sfdd`` section."""

    signals: tuple[SignalSpec, ...] = ()
    settings: SfddSettings = field(default_factory=SfddSettings)
    period: float = 0.1
    stale_after: float = 1.0
    interval: float = 1.0
    persistence: int = 1

    @classmethod
    def from_config(cls, node: ConfigNode | None) -> SfddConfig:
        if node is None:
            return cls()
        node.check_keys(["signals", "period", "stale_after", "interval", "persistence",
                         "window", "split",
                         "smoothing", "correlation", "hold", "signed", "references", "change",
                         "change_threshold", "stuck_ratio", "sigmas", "spread_ratio",
                         "strict"])
        signals: list[SignalSpec] = []
        items = node.get("signals")
        for item in items.list() if items is not None else []:
            item.check_keys(["topic", "field", "component"])
            spec = SignalSpec(item["topic"].str(),
                              item["field"].str() if item.get("field") is not None else "data",
                              item["component"].str() if item.get("component") is not None
                              else None)
            try:
                compile_field_path(spec.field)
            except ValueError as exc:
                raise item["field"].error(str(exc)) from None
            if spec.name in {s.name for s in signals}:
                raise item.error(f"signal {spec.name} is listed twice")
            signals.append(spec)
        kwargs: dict[str, Any] = {}
        for key in ("window", "smoothing"):
            if node.get(key) is not None:
                kwargs[key] = node[key].int(min=1)
        for key in ("split", "correlation", "hold", "change_threshold", "stuck_ratio",
                    "sigmas", "spread_ratio"):
            if node.get(key) is not None:
                kwargs[key] = node[key].float()
        for key in ("signed", "change", "strict"):
            if node.get(key) is not None:
                kwargs[key] = node[key].bool()
        if node.get("references") is not None:
            refs = []
            names = {s.name for s in signals}
            for r in node["references"].list(allow_single=True):
                spec = SignalSpec(r["topic"].str(), r["field"].str()
                                  if r.get("field") is not None else "data")
                if spec.name not in names:
                    raise r.error(f"reference {spec.name} is not one of the signals")
                refs.append(spec.name)
            kwargs["references"] = tuple(refs)
        try:
            settings = SfddSettings(**kwargs)
        except ValueError as exc:
            raise node.error(f"sfdd: {exc}") from None

        def seconds(key: str, default: float) -> float:
            return (node[key].float(min=0.0, min_exclusive=True) if node.get(key) is not None
                    else default)

        persistence = (node["persistence"].int(min=1) if node.get("persistence") is not None
                       else 1)
        return cls(tuple(signals), settings, seconds("period", 0.1),
                   seconds("stale_after", 1.0), seconds("interval", 1.0), persistence)


class SfddTap(ObserverBase):
    """Samples the signals on one clock and reports SFDD's verdict per signal."""

    type_name: ClassVar[str] = "sfdd"

    def __init__(self, config: SfddConfig) -> None:
        if len(config.signals) < 2:
            raise ValueError("diagnosis.sfdd.signals: SFDD needs at least two signals")
        self.config = config
        self.interval = config.interval
        self.resource = Resource()
        self.signals = config.signals
        names = [s.name for s in config.signals]
        self.detector = SfddDetector(names, config.settings)
        self._read: list[Callable[[Any], float]] = [compile_field_path(s.field)
                                                    for s in config.signals]
        self._by_topic: dict[str, list[int]] = {}
        for i, s in enumerate(config.signals):
            self._by_topic.setdefault(s.topic, []).append(i)
        n = len(names)
        self._rows = config.settings.window
        self._buffer = np.full((self._rows, n), np.nan)
        self._filled = 0
        self._next = 0
        self._held = np.full(n, np.nan)
        self._heard = np.full(n, -math.inf)
        self._non_finite = np.zeros(n, dtype=np.int64)
        self._unreadable = np.zeros(n, dtype=np.int64)
        self._tick: float | None = None
        self._streak = np.zeros(n, dtype=np.int64)
        self.cpu_seconds = 0.0
        self.windows = 0

    def interest(self) -> Interest:
        return Interest(decoded=frozenset(self._by_topic))

    def describe(self) -> str:
        return (f"sfdd over {len(self.signals)} signals, window {self._rows} x "
                f"{self.config.period:g} s")

    def _advance(self, now: float) -> None:
        period = self.config.period
        if self._tick is None:
            self._tick = now
        behind = int((now - self._tick) / period) - self._rows
        if behind > 0:
            # A gap longer than the window: only its last ``window`` rows can matter.
            self._tick += behind * period
        while self._tick <= now:
            fresh = (self._tick - self._heard) <= self.config.stale_after
            self._buffer[self._next] = np.where(fresh, self._held, np.nan)
            self._next = (self._next + 1) % self._rows
            self._filled = min(self._filled + 1, self._rows)
            self._tick += period

    def on_message(self, msg: MessageArrival) -> None:
        started = time.process_time()
        self._advance(msg.time)
        indices = self._by_topic.get(msg.topic, ())
        try:
            value = msg.value
        except Exception:
            value = None
        for i in indices:
            try:
                x = self._read[i](value)
            except (ValueError, TypeError):
                self._unreadable[i] += 1
                continue
            if not math.isfinite(x):
                self._non_finite[i] += 1
                continue
            self._held[i] = x
            self._heard[i] = msg.time
        self.cpu_seconds += time.process_time() - started

    def window(self) -> np.ndarray[Any, np.dtype[np.float64]]:
        """The filled rows, oldest first."""
        if self._filled < self._rows:
            return self._buffer[:self._filled].copy()
        return np.roll(self._buffer, -self._next, axis=0)

    def evaluate(self, now: float) -> list[Observation]:
        started = time.process_time()
        self._advance(now)
        verdicts = self.detector.judge(self.window())
        self.windows += 1
        out = [self._observation(now, i, v) for i, v in enumerate(verdicts)]
        self._non_finite[:] = 0
        self._unreadable[:] = 0
        self.cpu_seconds += time.process_time() - started
        return out

    def _observation(self, now: float, i: int, v: SignalVerdict) -> Observation:
        spec = self.signals[i]
        values = dict(v.values)
        if self._non_finite[i]:
            values["non_finite"] = float(self._non_finite[i])
        if self._unreadable[i]:
            values["unreadable"] = float(self._unreadable[i])
        self._streak[i] = self._streak[i] + 1 if v.faulty else 0
        if v.faulty and self._streak[i] < self.config.persistence:
            return Observation(now, OBSERVER_PREFIX + spec.field, Resource(topic=spec.topic),
                               Code.GENERAL_OK, values=values,
                               message=f"suspect ({v.pattern}, window {self._streak[i]} of "
                                       f"{self.config.persistence} needed): {v.reason}")
        if v.faulty:
            code = Code.NO_STATE_FITS
        elif v.pattern == "unjudged":
            code = Code.NOT_AVAILABLE
        else:
            code = Code.GENERAL_OK
        peers = f" (peers: {', '.join(v.peers)})" if v.peers else ""
        return Observation(now, OBSERVER_PREFIX + spec.field, Resource(topic=spec.topic), code,
                           values=values, message=f"{v.pattern}: {v.reason}{peers}")


def is_sfdd(obs: Observation) -> bool:
    return obs.observer.startswith(OBSERVER_PREFIX)


class StructuralModel:
    """Which signal belongs to which component (thesis 4.2, Fig. 4.2)."""

    def __init__(self, signals: Sequence[SignalSpec]) -> None:
        self.signals = tuple(signals)
        self._publishers: dict[str, str] = {}

    def on_graph(self, graph: GraphSnapshot) -> None:
        for info in graph.topics.values():
            if len(info.publishers) == 1:
                self._publishers[info.name] = info.publishers[0]

    def component(self, spec: SignalSpec) -> str:
        if spec.component is not None:
            return spec.component
        return self._publishers.get(spec.topic, spec.topic)

    def components(self) -> dict[str, list[SignalSpec]]:
        out: dict[str, list[SignalSpec]] = {}
        for s in self.signals:
            out.setdefault(self.component(s), []).append(s)
        return out

    def diagnose(self, faulty: set[str]) -> tuple[frozenset[str], dict[str, float]]:
        """Names to blame for the faulty signal names, and each component's health (share
        of its signals not faulty)."""
        blamed: set[str] = set()
        health: dict[str, float] = {}
        for comp, specs in self.components().items():
            bad = [s for s in specs if s.name in faulty]
            health[comp] = 1.0 - len(bad) / len(specs)
            if not bad:
                continue
            if len(bad) == len(specs):
                blamed.add(comp)
            else:
                blamed.update(s.topic for s in bad)
        return frozenset(blamed), health


@dataclass(frozen=True, slots=True)
class SignalState:
    """SFDD's latest verdict on one signal: judged or not, faulty or not."""

    spec: SignalSpec
    observation: Observation

    @property
    def judged(self) -> bool:
        return self.observation.code != Code.NOT_AVAILABLE

    @property
    def faulty(self) -> bool:
        """A fault pattern; an unjudged signal (``NOT_AVAILABLE``) is not faulty."""
        return self.observation.code == Code.NO_STATE_FITS


class SfddDiagnoser:
    """Diagnoses from SFDD's signal verdicts alone (``diagnosis.engine: sfdd``)."""

    engine = "sfdd"

    def __init__(self, config: SfddConfig) -> None:
        self.config = config
        self.model = StructuralModel(config.signals)
        self._spec = {(OBSERVER_PREFIX + s.field, s.topic): s for s in config.signals}
        self.states: dict[str, SignalState] = {}
        self._current: Diagnosis | None = None
        self.cpu_seconds = 0.0

    def on_graph(self, graph: GraphSnapshot) -> None:
        self.model.on_graph(graph)

    def feed(self, observations: Sequence[Observation]) -> bool:
        """Take SFDD's observations; ``True`` when some verdict changed."""
        changed = False
        for obs in observations:
            spec = self._spec.get((obs.observer, obs.resource.topic or ""))
            if spec is None:
                continue
            old = self.states.get(spec.name)
            if old is None or old.observation.code != obs.code:
                changed = True
            self.states[spec.name] = SignalState(spec, obs)
        return changed

    def faulty(self) -> set[str]:
        return {n for n, s in self.states.items() if s.faulty}

    def verdict(self, components: frozenset[str]) -> str:
        """``confirmed``: a signal of these components (or their topics) is faulty;
        ``questioned``: some are judged and all judged ones are healthy; ``unjudged``."""
        mine = [s for s in self.states.values()
                if s.spec.topic in components or self.model.component(s.spec) in components]
        if any(s.faulty for s in mine):
            return "confirmed"
        if any(s.judged for s in mine):
            return "questioned"
        return "unjudged"

    def diagnosis(self, now: float) -> Diagnosis:
        faulty = self.faulty()
        blamed, health = self.model.diagnose(faulty)
        failed = tuple(sorted((s.observation for s in self.states.values() if s.faulty),
                              key=lambda o: (o.observer, o.resource.label())))
        if blamed:
            worst = ", ".join(f"{c} {100 * h:.0f} %" for c, h in sorted(health.items())
                              if h < 1.0)
            text = (f"SFDD: {', '.join(sorted(faulty))} stopped following the signals "
                    f"correlated with them; blamed {', '.join(sorted(blamed))} (component "
                    f"health: {worst})")
            return Diagnosis(now, (blamed,), failed, text, True, "sfdd", "")
        return Diagnosis(now, (), failed, "", True, "sfdd", "")

    def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None:
        started = time.process_time()
        try:
            if not self.feed(observations) and self._current is not None:
                return None
            d = self.diagnosis(now)
            if self._current is not None and d.candidates == self._current.candidates:
                return None
            self._current = d
            return d
        finally:
            self.cpu_seconds += time.process_time() - started


def signal_components(config: SfddConfig, publishers: Mapping[str, str]) -> dict[str, str]:
    """Signal name -> component, given topic publishers (for reports)."""
    return {s.name: s.component or publishers.get(s.topic, s.topic) for s in config.signals}


__all__ = ["OBSERVER_PREFIX", "SfddConfig", "SfddDiagnoser", "SfddTap", "SignalSpec",
           "StructuralModel", "is_sfdd"]
