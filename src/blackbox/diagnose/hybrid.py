"""CBD proposes, SFDD confirms or questions (thesis section 7.3), and the engine switch.

The thesis's future work: "when the CBD algorithm produces a fault from a certain component,
it can be verified by the underlying SFDD algorithm if it produced a fault from the same
component as well", both on one structural model. Here the structural model is the robot
model's component names (nodes, topics, hardware): each SFDD signal belongs to a topic and
a component (its publisher node or a configured hardware name), which are names in the CBD
model too.

For every CBD candidate SFDD says ``confirmed`` (a signal of one of its components is
faulty), ``questioned`` (it watches some of them and all it can judge are healthy) or
``unjudged`` (it watches none, or they are silent: kills and stalls, where SFDD is blind).
Candidates are re-ranked confirmed, unjudged, questioned, each group in CBD's order; a
questioned candidate is kept, since CBD's verdict is sound for what the observers saw and
SFDD's silence is not proof. A fault only SFDD sees (CBD's thresholds are quiet) is added
as the last candidate. The diagnosis's ``agreement`` says which engines agree: ``agree``,
``agree: healthy``, ``cbd only``, ``questioned by sfdd`` or ``sfdd only``.

``diagnosis.hybrid: verify`` (default ``rank``) takes section 7.3 literally, SFDD as the check
"if a fault has actually occurred": when every failed CBD observation judges values (no rate,
timeout or liveness alarm, which SFDD cannot see) and SFDD questions every CBD candidate, the
alarm is withheld: no candidates, agreement ``withheld: sfdd questions cbd``. This trades
CBD's soundness for fewer false alarms from value thresholds; ``rank`` never drops a
candidate.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from blackbox.diagnose.live import DiagnosisSettings, LiveDiagnoser
from blackbox.diagnose.robot_model import is_rate_type
from blackbox.diagnose.sfdd_live import SfddDiagnoser, SfddTap, is_sfdd
from blackbox.events import GraphSnapshot
from blackbox.model import Diagnosis, Observation
from blackbox.observe.base import Observer

ENGINES = ("cbd", "sfdd", "hybrid")
HYBRID_MODES = ("rank", "verify")

_ORDER = {"confirmed": 0, "unjudged": 1, "questioned": 2}


class CbdDiagnoser:
    """The consistency-based engine (:class:`LiveDiagnoser`) with its CPU time counted and
    SFDD's observations kept out of its model."""

    engine = "cbd"

    def __init__(self, observers: Sequence[Observer], settings: DiagnosisSettings) -> None:
        self.live = LiveDiagnoser([o for o in observers if not isinstance(o, SfddTap)],
                                  settings)
        self.cpu_seconds = 0.0
        self.current: Diagnosis | None = None

    def on_graph(self, graph: GraphSnapshot) -> None:
        started = time.process_time()
        self.live.on_graph(graph)
        self.cpu_seconds += time.process_time() - started

    def replace_observers(self, observers: Sequence[Observer], graph: GraphSnapshot | None
                          ) -> None:
        self.live.replace_observers([o for o in observers if not isinstance(o, SfddTap)], graph)

    def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None:
        started = time.process_time()
        try:
            d = self.live.update(now, [o for o in observations if not is_sfdd(o)])
            if d is not None:
                self.current = d
            return d
        finally:
            self.cpu_seconds += time.process_time() - started


class HybridDiagnoser:
    """CBD's candidates, each confirmed, questioned or unjudged by SFDD."""

    engine = "hybrid"

    def __init__(self, cbd: CbdDiagnoser, sfdd: SfddDiagnoser, mode: str = "rank") -> None:
        if mode not in HYBRID_MODES:
            raise ValueError(f"hybrid mode must be one of {', '.join(HYBRID_MODES)}")
        self.cbd = cbd
        self.sfdd = sfdd
        self.mode = mode
        self._current: Diagnosis | None = None
        self._own_cpu = 0.0

    @property
    def cpu_seconds(self) -> float:
        return self.cbd.cpu_seconds + self.sfdd.cpu_seconds + self._own_cpu

    def on_graph(self, graph: GraphSnapshot) -> None:
        self.cbd.on_graph(graph)
        self.sfdd.on_graph(graph)

    def replace_observers(self, observers: Sequence[Observer], graph: GraphSnapshot | None
                          ) -> None:
        self.cbd.replace_observers(observers, graph)

    def update(self, now: float, observations: Sequence[Observation]) -> Diagnosis | None:
        self.cbd.update(now, observations)
        self.sfdd.update(now, observations)
        started = time.process_time()
        try:
            d = self.combine(now)
            old = self._current
            if old is not None and (d.candidates, d.agreement) == (old.candidates,
                                                                    old.agreement):
                return None
            self._current = d
            return d
        finally:
            self._own_cpu += time.process_time() - started

    def combine(self, now: float) -> Diagnosis:
        cbd = self.cbd.current
        proposed = cbd.candidates if cbd is not None else ()
        verdicts = [self.sfdd.verdict(c) for c in proposed]
        ranked = [c for _, _, c in sorted(((_ORDER[v], i, c) for i, (c, v)
                                           in enumerate(zip(proposed, verdicts, strict=True))),
                                          key=lambda t: (t[0], t[1]))]
        blamed, _ = self.sfdd.model.diagnose(self.sfdd.faulty())
        candidates = list(ranked)
        if blamed and "confirmed" not in verdicts and blamed not in candidates:
            candidates.append(blamed)
        values_only = cbd is not None and bool(cbd.failed) and not any(
            is_rate_type(o.observer) for o in cbd.failed)
        if (self.mode == "verify" and proposed and values_only
                and all(v == "questioned" for v in verdicts)):
            candidates = [blamed] if blamed else []
            agreement = "withheld: sfdd questions cbd"
        elif not proposed and not blamed:
            agreement = "agree: healthy"
        elif not proposed:
            agreement = "sfdd only"
        elif "confirmed" in verdicts:
            agreement = "agree"
        elif "unjudged" in verdicts:
            agreement = "cbd only"
        else:
            agreement = "questioned by sfdd"
        sfdd_failed = [s.observation for s in self.sfdd.states.values() if s.faulty]
        failed = tuple([*(cbd.failed if cbd is not None else ()), *sfdd_failed])
        words = [f"[hybrid: {agreement}]"]
        if cbd is not None and cbd.explanation:
            words.append(cbd.explanation)
        if proposed:
            words.append("SFDD on CBD's candidates: " + "; ".join(
                f"{{{', '.join(sorted(c))}}} {v}" for c, v in zip(proposed, verdicts,
                                                                  strict=True)) + ".")
        if blamed:
            words.append(self.sfdd.diagnosis(now).explanation)
        complete = cbd.complete if cbd is not None else True
        return Diagnosis(now, tuple(candidates), failed, " ".join(words), complete, "hybrid",
                         agreement)


Diagnoser = CbdDiagnoser | SfddDiagnoser | HybridDiagnoser


def make_diagnoser(observers: Sequence[Observer], settings: DiagnosisSettings,
                   engine: str | None = None) -> tuple[Diagnoser, list[Observer]]:
    """The diagnoser ``settings.engine`` (or ``engine``, which wins) asks for, and the
    observers it adds (SFDD's signal tap). ``ValueError`` for an engine without signals."""
    chosen = engine or settings.engine
    if chosen not in ENGINES:
        raise ValueError(f"unknown diagnosis engine {chosen!r}; expected {', '.join(ENGINES)}")
    if chosen == "cbd":
        return CbdDiagnoser(observers, settings), []
    if len(settings.sfdd.signals) < 2:
        raise ValueError(f"diagnosis engine {chosen} needs diagnosis.sfdd.signals (two or "
                         "more numeric fields of topics)")
    tap = SfddTap(settings.sfdd)
    sfdd = SfddDiagnoser(settings.sfdd)
    if chosen == "sfdd":
        return sfdd, [tap]
    return HybridDiagnoser(CbdDiagnoser(observers, settings), sfdd, settings.hybrid), [tap]


__all__ = ["ENGINES", "HYBRID_MODES", "CbdDiagnoser", "HybridDiagnoser", "make_diagnoser"]
