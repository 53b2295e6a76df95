"""The station's words for operators: a robot's diagnosis explained at a glance.

Kept out of the storage code so that wording can change without touching SQL, and every
backend explains a diagnosis the same way.
"""

from __future__ import annotations

from collections.abc import Sequence


def unnamed_entity(instance_id: int) -> str:
    """How an entity is named before its description arrived: by its instance id."""
    return f"#{instance_id}"


def rectified(entity: str) -> str:
    """A rectification: ``entity`` is diagnosed faulty no more."""
    return f"{entity} is no longer diagnosed faulty"


def explain(robot: str, components: Sequence[str], causes: dict[str, str],
            actions: dict[str, str], degraded: Sequence[str] = (), *, stale: bool = False,
            online: bool = True) -> str:
    """The current diagnosis in words an operator reads at a glance."""
    parts: list[str] = []
    if not online:
        parts.append(f"{robot}'s black box has stopped; what is shown is its last state.")
    elif stale:
        parts.append(f"{robot} has not been heard for a while; what is shown is its last "
                     "known state and may be out of date.")
    if components:
        names = ", ".join(components)
        verb = "is" if len(components) == 1 else "are"
        parts.append(f"The black box diagnoses {names}: {names} {verb} not working.")
        for name in components:
            if causes.get(name):
                parts.append(f"{name}: {causes[name]}.")
            if actions.get(name):
                parts.append(f"What to do for {name}: {actions[name]}.")
    elif degraded:
        parts.append(f"No failure diagnosed, but {', '.join(degraded)} "
                     f"{'shows' if len(degraded) == 1 else 'show'} threshold exceedances.")
    else:
        parts.append("No failure diagnosed.")
    return " ".join(p.replace("..", ".") for p in parts)
