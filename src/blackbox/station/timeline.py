"""A robot's health history as a picture: one lane per entity, coloured by status over time.

What a person reconstructing an incident looks at first: which entity was red when, for how
long, in what order. On the station the lanes come from the status history it keeps
(:mod:`blackbox.station.status_history`): every status an entity had, DEGRADED and UNKNOWN
included, and the robot lane is the robot's own derived status (the rule of its badge).
Where no history was kept (a robot's own log, a station database from before it), the lanes
are rebuilt from events: an entity is NOT_OPERATIONAL from a ``failure`` naming it until
the ``rectification`` that clears it (or the window's end), the robot lane is red while any
of its entities is; before the first event of an entity in the window its state is the one
its last earlier failure or rectification left (OPERATIONAL when none). Either way,
``exceedance`` events are yellow ticks (they have no end), and acknowledgements are marked.

Pure: :func:`build` takes plain records, :func:`svg` returns markup (escaped), so the web
page and an export draw the same picture.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from html import escape
from itertools import pairwise
from urllib.parse import urlencode

from blackbox.record.store import LogEntry

COLOURS = {"OPERATIONAL": "#2da44e", "DEGRADED": "#d4a72c", "NOT_OPERATIONAL": "#cf222e",
           "UNKNOWN": "#8c959f"}
WIDTH, LANE_HEIGHT, LABEL_WIDTH, TOP = 1000, 20, 190, 22
"""The picture's geometry in pixels (SVG user units): the SVG and the PNG share it."""
ZOOMS = {"5m": 300.0, "1h": 3600.0, "1d": 86400.0, "7d": 7 * 86400.0}
"""The windows an operator picks, from the last five minutes to a week."""


@dataclass(frozen=True, slots=True)
class Happening:
    """One stored event, as much of it as the timeline needs."""

    time: float
    kind: str
    entity: str
    acknowledged_at: float | None = None


@dataclass(frozen=True, slots=True)
class Span:
    start: float
    end: float
    status: str


@dataclass(frozen=True, slots=True)
class Mark:
    time: float
    kind: str
    """``exceedance`` or ``acknowledged``."""


@dataclass(frozen=True, slots=True)
class Lane:
    entity: str
    spans: tuple[Span, ...]
    marks: tuple[Mark, ...]


def _spans(changes: Sequence[tuple[float, str]], start: float, end: float,
           initial: str) -> tuple[Span, ...]:
    out: list[Span] = []
    status, since = initial, start
    for t, new in sorted(changes):
        t = min(max(t, start), end)
        if new == status:
            continue
        if t > since:
            out.append(Span(since, t, status))
        status, since = new, t
    if end > since:
        out.append(Span(since, end, status))
    return tuple(out)


@dataclass(frozen=True, slots=True)
class Recorded:
    """The statuses kept for one lane: the one at the window's start and the changes in it."""

    initial: str
    changes: Sequence[tuple[float, str]]


def build(robot: str, entities: Sequence[str], happenings: Sequence[Happening],
          start: float, end: float, before: Mapping[str, str] | None = None,
          recorded: Mapping[str, Recorded] | None = None,
          robot_recorded: Recorded | None = None) -> list[Lane]:
    """The lanes, robot first then ``entities`` in order. ``happenings`` are the events in
    ``[start, end]``; ``before[name]`` the status an entity had at ``start``. An entity in
    ``recorded`` (the robot lane with ``robot_recorded``) is drawn from its kept statuses,
    the others from their failures and rectifications."""
    before = before or {}
    recorded = recorded or {}
    changes: dict[str, list[tuple[float, str]]] = {
        name: list(recorded[name].changes) if name in recorded else [] for name in entities}
    marks: dict[str, list[Mark]] = {name: [] for name in entities}
    for h in happenings:
        if h.entity not in changes:
            continue
        if h.kind == "failure" and h.entity not in recorded:
            changes[h.entity].append((h.time, "NOT_OPERATIONAL"))
        elif h.kind == "rectification" and h.entity not in recorded:
            changes[h.entity].append((h.time, "OPERATIONAL"))
        elif h.kind == "exceedance":
            marks[h.entity].append(Mark(h.time, "exceedance"))
        if h.acknowledged_at is not None and start <= h.acknowledged_at <= end:
            marks[h.entity].append(Mark(h.acknowledged_at, "acknowledged"))
    lanes = [Lane(name, _spans(changes[name], start, end,
                               recorded[name].initial if name in recorded
                               else before.get(name, "OPERATIONAL")),
                  tuple(sorted(marks[name], key=lambda m: m.time))) for name in entities]
    if robot_recorded is None:
        return [_robot_lane(robot, lanes, start, end), *lanes]
    marks_all = tuple(sorted((m for lane in lanes for m in lane.marks), key=lambda m: m.time))
    own = Lane(robot, _spans(robot_recorded.changes, start, end, robot_recorded.initial),
               marks_all)
    return [own, *lanes]


def _robot_lane(robot: str, lanes: Sequence[Lane], start: float, end: float) -> Lane:
    """Red while any entity is red: the union of the entities' failure spans."""
    edges = sorted({start, end, *(t for lane in lanes for s in lane.spans
                                  for t in (s.start, s.end))})
    changes: list[tuple[float, str]] = []
    for a, b in pairwise(edges):
        mid = (a + b) / 2
        red = any(s.start <= mid < s.end and s.status == "NOT_OPERATIONAL"
                  for lane in lanes for s in lane.spans)
        changes.append((a, "NOT_OPERATIONAL" if red else "OPERATIONAL"))
    marks = tuple(sorted((m for lane in lanes for m in lane.marks), key=lambda m: m.time))
    return Lane(robot, _spans(changes, start, end, "OPERATIONAL"), marks)


def clock(t: float, window: float) -> str:
    """A time on the picture's axis: the clock, with the date once the window is long."""
    at = datetime.fromtimestamp(t, UTC)
    return at.strftime("%H:%M:%S" if window <= 3600 else "%m-%d %H:%M")


def svg(lanes: Sequence[Lane], start: float, end: float, *, robot_ref: str = "",
        width: int = WIDTH, lane_height: int = LANE_HEIGHT,
        label_width: int = LABEL_WIDTH) -> str:
    """The timeline as an SVG document; with ``robot_ref`` each span links to the page of
    that entity and moment, its events and charts (the web page), without it the picture
    stands alone."""
    window = max(end - start, 1e-9)
    plot = width - label_width - 10
    top = TOP
    height = top + lane_height * len(lanes) + 6

    def x(t: float) -> float:
        return label_width + (t - start) / window * plot

    role = 'role="group" aria-label="Health timeline"' if robot_ref else 'role="img"'
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" class="timeline" {role} '
           f'viewBox="0 0 {width} {height}" width="{width}" height="{height}" '
           f'font-family="system-ui, sans-serif" font-size="12">',
           f"<title>Health timeline {escape(clock(start, window))} - "
           f"{escape(clock(end, window))} UTC</title>",
           f'<rect x="0" y="0" width="{width}" height="{height}" fill="#fff"/>']
    for i in range(5):
        t = start + window * i / 4
        anchor = "start" if i == 0 else ("end" if i == 4 else "middle")
        out.append(f'<text x="{x(t):.1f}" y="14" text-anchor="{anchor}" fill="#656d76">'
                   f"{escape(clock(t, window))}</text>")
    for row, lane in enumerate(lanes):
        y = top + row * lane_height
        label = lane.entity if len(lane.entity) <= 28 else "…" + lane.entity[-27:]
        out.append(f'<g class="lane" data-entity="{escape(lane.entity)}">'
                   f'<text x="4" y="{y + lane_height - 6}" fill="#1f2328">'
                   f"<title>{escape(lane.entity)}</title>{escape(label)}</text>")
        for span in lane.spans:
            rect = (f'<rect class="span s-{span.status.lower().replace("_", "-")}" '
                    f'x="{x(span.start):.2f}" y="{y + 3}" '
                    f'width="{max(x(span.end) - x(span.start), 0.5):.2f}" '
                    f'height="{lane_height - 6}" fill="{COLOURS.get(span.status, "#8c959f")}">'
                    f"<title>{escape(lane.entity)}: {span.status} "
                    f"{escape(clock(span.start, window))} - {escape(clock(span.end, window))}"
                    f"</title></rect>")
            if robot_ref:
                query = {"r": robot_ref, "since": _iso(span.start),
                         "until": _iso(span.end + 1), "status": span.status}
                if row > 0:
                    query["entity"] = lane.entity
                rect = f'<a href="/moment?{escape(urlencode(query))}">{rect}</a>'
            out.append(rect)
        for mark in lane.marks:
            colour = "#1f2328" if mark.kind == "acknowledged" else COLOURS["DEGRADED"]
            mx = x(mark.time)
            shape = (f'<path d="M{mx - 4:.1f},{y + lane_height - 1} l4,-6 l4,6 z" '
                     if mark.kind == "acknowledged" else
                     f'<rect x="{mx - 1:.1f}" y="{y}" width="2" height="{lane_height}" ')
            out.append(f'{shape}class="mark m-{mark.kind}" fill="{colour}">'
                       f"<title>{mark.kind} {escape(clock(mark.time, window))}</title>"
                       + ("</path>" if mark.kind == "acknowledged" else "</rect>"))
        out.append("</g>")
    out.append("</svg>")
    return "".join(out)


def _iso(t: float) -> str:
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%dT%H:%M:%S")


def from_log(entries: Iterable[LogEntry]) -> tuple[list[str], list[Happening]]:
    """The entities and happenings a robot's own health log records (``blackbox log export
    --timeline``, for an incident report without a station): its ``failure`` rows name
    failures and rectifications (``payload.events``, or the older ``components`` with a
    ``category``), its ``exceedance`` rows the exceedances. Entities in order of first
    appearance."""
    names: dict[str, None] = {}
    out: list[Happening] = []

    def add(t: float, kind: str, entity: str) -> None:
        if entity:
            names.setdefault(entity, None)
            out.append(Happening(t, kind, entity))

    for entry in entries:
        payload = entry.payload if isinstance(entry.payload, dict) else {}
        t = float(entry.time)
        if entry.kind == "exceedance":
            add(t, "exceedance", str(entry.entity or ""))
        elif entry.kind == "failure":
            named = payload.get("events")
            if isinstance(named, list):
                for item in named:
                    if isinstance(item, dict) and item.get("kind") in ("failure",
                                                                       "rectification"):
                        add(t, str(item["kind"]), str(item.get("entity") or ""))
                continue
            kind = "rectification" if payload.get("category") == "rectification" \
                else "failure"
            for component in payload.get("components") or []:
                add(t, kind, str(component))
    return list(names), out
