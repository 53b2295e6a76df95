"""Helpers shared by the diagnosis engine tests."""

from __future__ import annotations

from blackbox.diagnose.engine import DiagnosisEngine
from blackbox.model import Code, Observation


def observations(engine: DiagnosisEngine, failed: set[tuple[str, str]],
                 unknown: set[tuple[str, str]] = frozenset(), t: float = 1.0
                 ) -> list[Observation]:
    """One observation per observation of the engine's model: failed, unknown or OK, by
    (observer type, node or topic)."""
    out = []
    for spec in engine.model.observations:
        key = (spec.type, spec.resource.node or spec.resource.topic)
        code = (Code.NOT_AVAILABLE if key in unknown
                else Code.NO_STATE_FITS if key in failed else Code.GENERAL_OK)
        out.append(Observation(t, spec.type, spec.resource, code))
    return out
