"""Scoring a diagnosis engine's verdicts as detections, so engines compare on one footing.

The observation-level scores (:func:`~blackbox.evaluate.metrics.score_run` on observations)
are the observers' and do not change with the engine. To compare CBD, SFDD and the hybrid,
each engine's diagnoses are read as detections: while a diagnosis ranks a component in its
first candidate, that component is *reported* (what the UCMS mapping raises as a Failure
Event; lower-ranked candidates are alternatives, not claims). Every reported component becomes one
synthetic observation key (observer ``diagnosis``), faulty from the diagnosis that first
lists it until the next diagnosis that does not, and those observations are scored with the
same episode, TP/FP/FN and delay definitions as the observers' (docs/evaluation.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from blackbox.model import Code, Diagnosis, Observation, Resource

OBSERVER = "diagnosis"
_EPSILON = 1e-6


def diagnosis_observations(diagnoses: Sequence[Diagnosis], topics: Mapping[str, str],
                           end: float) -> list[Observation]:
    """Synthetic observations of what each diagnosis reports; ``topics`` maps topic names to
    publishers (a topic is a topic resource, any other name a node resource)."""
    ordered = sorted(diagnoses, key=lambda d: d.time)
    universe = sorted({c for d in ordered for c in (d.candidates[0] if d.candidates else ())})
    resources = {c: Resource(topic=c) if c in topics else Resource(node=c) for c in universe}
    out: list[Observation] = []
    for k, d in enumerate(ordered):
        named = d.candidates[0] if d.candidates else frozenset()
        until = ordered[k + 1].time - _EPSILON if k + 1 < len(ordered) else end
        for c in universe:
            code = Code.NO_STATE_FITS if c in named else Code.GENERAL_OK
            out.append(Observation(d.time, OBSERVER, resources[c], code))
            if until > d.time:
                out.append(Observation(until, OBSERVER, resources[c], code))
    return out
