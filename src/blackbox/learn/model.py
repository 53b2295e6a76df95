"""From a recording of a healthy run to learned observer entries, one block per topic and
per node, each with comments saying what was measured and what could not be learned.

The rules (also in docs/learn.md):

* **Rate** (``hz``) per topic and publisher group (one group of all publishers when a topic
  has one publisher, one group per publisher otherwise): the inter-arrival periods go
  through :func:`blackbox.learn.stats.learn_bounds` with a margin of at least
  ``RATE_TOLERANCE`` (40 %) of the median period, over a window of ``MAX_DELAY`` seconds
  of messages (the longest allowed: that margin sets the band whatever the window, and a
  pause of ``p`` seconds of a loaded robot computer lengthens the mean period of a
  ``W``-second window by about ``p / W``: a one-second window left the band on a 0.4 s
  pause, a two-second one takes 0.8 s).
* **Timeout**: ``max(2 x longest healthy gap, 5 x median period, 1 s)``.
* Topics whose periods spread widely (p90 / p10 > ``IRREGULAR``) are event-driven: no rate
  or timeout observer, only a comment.
* **Message age** (``timestamp``) for messages with a ``header.stamp``: bounds by the same
  rule with a margin of at least ``AGE_FLOOR`` seconds.
* **Values** (one ``fields`` observer per topic): numeric scalars, and for numeric arrays
  their mean, min, max and the fraction of elements that are finite and inside the learned
  element range (widened by 10 % of its span): bounds by the same rule. Constant fields,
  counters and monotonic fields (clocks, odometers) are listed, not observed; discrete
  fields (a few integer levels) must stay within their learned levels +- 0.5. A numeric
  value filtered over 3 or more samples also gets a lower bound on the window's standard
  deviation, a quarter of its 0.1 % quantile while learning, so a frozen value is seen.
* **Nodes**: ``activated`` for every node seen running; ``resources`` with upper bounds
  ``cpu < hi + max(hi - lo, hi, 10 %)`` (:func:`cpu_limit`) and ``memory < hi + max(hi -
  lo, hi / 4, 16 MB)`` where lo..hi is the robust band of the 5-sample mean.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from blackbox.learn.fields import classify
from blackbox.learn.recording import FieldRecord, NodeRecord, Recording, TopicRecord
from blackbox.learn.relations import (
    Relation,
    RelationsLearned,
    learn_relations,
    liveness_comments,
    liveness_entry,
    relation_comments,
    relation_entry,
)
from blackbox.learn.stats import (
    MIN_SAMPLES,
    Bounds,
    learn_bounds,
    lengthened,
    quantile,
    round_down,
    round_up,
)

MAX_DELAY = 2.0
"""Largest filter window, in seconds of messages: a longer window delays detection."""
IRREGULAR = 4.0
TIMEOUT_FLOOR = 1.0
"""Two minutes on a quiet machine never see the pauses a loaded robot computer makes: a
learned 0.5 s raised 3-6 time-outs in a healthy half hour of the real diffdrive robots
while a test suite started beside them."""
AGE_FLOOR = 0.25
RATE_TOLERANCE = 0.4
"""The least margin of a learned period band, as a fraction of the median period: a loaded
robot's nodes run 10-30 % slow for seconds (the real diffdrive robots' 100 Hz IMU at
75-90 Hz while a test suite started beside them; 64 and 45 false-alarm episodes of learned
2-4 % bands in a healthy half hour). A rate fault (a publisher at 60 % of its rate or
less, a duplicate publisher) still leaves the band; a stopped one is the time-out's."""
RESOURCE_WINDOW = 5
START_UP_TIME = 1.0
MIN_STUCK_WINDOW = 3
"""Smallest filter window that also watches the spread of a value (a frozen value)."""
LOGGING_TOPICS = frozenset({"/rosout", "/rosout_agg"})
STATE = {"number": 1, "name": "nominal"}


@dataclass
class Block:
    """One learned block of the configuration: observer entries and the comments on them."""

    id: str
    comments: list[str] = field(default_factory=list)
    entries: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    """What could not be learned, said in the block and in the file's summary."""


@dataclass
class Learned:
    """Everything ``blackbox learn`` writes."""

    source: str
    duration: float
    nodes: list[Block]
    topics: list[Block]
    graph: dict[str, tuple[tuple[str, ...], tuple[str, ...]]]
    """node -> (published topics, subscribed topics)"""
    notes: list[str]
    relations: list[Block] = field(default_factory=list)
    """One block per pair of topics with learned relations (``blackbox.learn.relations``)."""

    @property
    def blocks(self) -> list[Block]:
        return [*self.nodes, *self.topics, *self.relations]


def _s(x: float) -> str:
    return f"{x:.4g}"


def quantity_name(path: str, summary: str = "") -> str:
    name = re.sub(r"[^A-Za-z0-9_]+", "_", path).strip("_") or "value"
    if name[0].isdigit():
        name = "f_" + name
    return f"{name}_{summary}" if summary else name


def _max_window(periods: np.ndarray | None) -> int:
    if periods is None or periods.size == 0:
        return 1
    median = float(np.median(periods))
    return max(1, int(MAX_DELAY / median)) if median > 0 else 1


def _filter(bounds: Bounds) -> dict[str, Any]:
    if bounds.window <= 1:
        return {"type": "nofilter"}
    return {"type": "mean", "window_size": bounds.window}


def _between(lower: float, upper: float) -> dict[str, Any]:
    return {"value": {"type": "in_between", "lower_bound": round_down(lower),
                      "upper_bound": round_up(upper)}}


def _bounds_note(b: Bounds, unit: str = "") -> str:
    how = (f"catches a level shift of {b.shift_caught:.2g} noise std" if b.sigma > 0
           else "noise-free while learning")
    if b.sigma > 0 and not b.sensitive:
        how += " (no window up to the delay limit reached the 2 std target)"
    return (f"window {b.window}, filtered band {_s(b.band[0])}..{_s(b.band[1])}{unit}, "
            f"noise std {_s(b.sigma)}{unit}: {how}")


def learn_model(rec: Recording) -> Learned:
    notes: list[str] = []
    if not rec.topics and not rec.nodes:
        notes.append("the source showed no node and no topic: nothing could be learned")
    elif not any(t.total for t in rec.topics.values()):
        notes.append(f"no message arrived on any topic during {rec.duration:.0f} s: no rate "
                     "or value observer could be learned")
    node_blocks = [_node_block(n, rec) for n in sorted(rec.nodes.values(), key=lambda n: n.name)]
    related = learn_relations(rec)
    topic_blocks = [_topic_block(t, rec, related) for t in sorted(rec.topics.values(),
                                                                   key=lambda t: t.name)]
    relation_blocks = _relation_blocks(related)
    notes.extend(related.notes)
    for b in [*node_blocks, *topic_blocks]:
        notes.extend(f"{b.id}: {n}" for n in b.notes)
    if rec.late_topics:
        notes.append("appeared after discovery, not learned (run learn again): "
                     + ", ".join(sorted(rec.late_topics)))
    graph: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {}
    for name in sorted(rec.nodes):
        pub = tuple(sorted(t.name for t in rec.topics.values() if name in t.publishers))
        sub = tuple(sorted(t.name for t in rec.topics.values() if name in t.subscribers))
        graph[name] = (pub, sub)
    return Learned(rec.source, rec.duration, node_blocks, topic_blocks, graph, notes,
                   relation_blocks)


def _relation_blocks(related: RelationsLearned) -> list[Block]:
    pairs: dict[tuple[str, str], list[Relation]] = {}
    for r in related.relations:
        pairs.setdefault(r.topics, []).append(r)
    blocks = []
    for pair, relations in sorted(pairs.items()):
        block = Block(f"relation {pair[0]} {pair[1]}")
        block.comments.extend(relation_comments(relations))
        block.entries.append(relation_entry(pair, relations))
        blocks.append(block)
    return blocks


# ---- nodes -----------------------------------------------------------------------------------

def _node_block(node: NodeRecord, rec: Recording) -> Block:
    block = Block(f"node {node.name}")
    if not node.alive_seen:
        block.notes.append("never seen running: not observed")
        return block
    block.entries.append({"type": "activated", "node": node.name,
                          "start_up_time": START_UP_TIME})
    for a, b in node.dead_spans:
        end = "the end" if b is None else f"{b - rec.started:.1f} s"
        block.notes.append(f"not running from {a - rec.started:.1f} s to {end} of the run; "
                           "its topics were learned from the time it ran")
    if node.name in rec.late_nodes:
        block.notes.append("appeared after discovery: no resource samples were taken")
        return block
    cpu, memory = node.cpu.array(), node.memory.array()
    if cpu.size < RESOURCE_WINDOW or memory.size < RESOURCE_WINDOW:
        why = node.missing_reason or "too few samples"
        block.notes.append(f"CPU and memory not learned ({cpu.size} samples): {why}")
        return block
    cpu_lo, cpu_hi = _band(cpu)
    mem_lo, mem_hi = _band(memory)
    cpu_bound = cpu_limit(cpu_lo, cpu_hi)
    mem_limit = mem_hi + max(mem_hi - mem_lo, mem_hi / 4, 16e6)
    block.comments.append(f"cpu {_s(cpu_lo)}..{_s(cpu_hi)} % and memory {_s(mem_lo / 1e6)}.."
                          f"{_s(mem_hi / 1e6)} MB (mean of {RESOURCE_WINDOW} samples) over "
                          f"{cpu.size} samples")
    block.entries.append({
        "type": "resources", "node": node.name,
        "cpu_filter": {"type": "mean", "window_size": RESOURCE_WINDOW},
        "memory_filter": {"type": "mean", "window_size": RESOURCE_WINDOW},
        "states": [{**STATE, "cpu": {"value": {"type": "less_than",
                                               "less_than": round_up(cpu_bound, 3)}},
                    "memory": {"value": {"type": "less_than",
                                         "less_than": round_up(mem_limit, 3)}}}]})
    return block


def cpu_limit(lo: float, hi: float) -> float:
    """The learned upper bound of a node's CPU (percent of one core) from its band lo..hi.

    A node's CPU share rises with the host's contention, not only with its own work (more
    wake-ups that find a cold cache, more context switches): a node learned at about 8 % of
    a core on real ROS 2 went over the 13.2 % that the former margin ``max(hi - lo, hi / 2,
    5 %)`` gave it while two test suites ran beside it. A fault worth reporting is far
    larger (a busy thread is a whole core), so the margin is at least the node's own high
    mark and at least 10 points.
    """
    return hi + max(hi - lo, hi, 10.0)


def _band(x: np.ndarray) -> tuple[float, float]:
    from blackbox.learn.stats import rolling_mean

    f = rolling_mean(x, min(RESOURCE_WINDOW, x.size))
    return quantile(f, 0.001), quantile(f, 0.999)


# ---- topics ----------------------------------------------------------------------------------

def _topic_block(topic: TopicRecord, rec: Recording, related: RelationsLearned) -> Block:
    block = Block(f"topic {topic.name}")
    pubs = ", ".join(sorted(topic.publishers)) or "none"
    block.comments.append(f"{topic.type or 'type unknown'} from {pubs}: {topic.total:,} "
                          f"messages in {rec.duration:.0f} s")
    if topic.name in LOGGING_TOPICS:
        block.comments.append("logging topic: its traffic is whatever nodes log; not observed")
        return block
    if topic.total == 0:
        block.notes.append(f"no message in {rec.duration:.0f} s: neither rate nor values "
                           "learned")
        return block
    if topic.unmeasured:
        block.comments.append(f"{topic.unmeasured} message(s) inside measurement gaps not "
                              "learned from")
    if topic.split_gaps:
        block.comments.append(f"{topic.split_gaps} gap(s) while a publisher was not running "
                              "left out of the periods (or while it was not measured)")
    periods = _rate_entries(topic, block)
    trends = related.trends.get(topic.name, [])
    block.comments.extend(trends)
    related_fields = related.related.get(topic.name, set())
    if related_fields:
        block.comments.append("judged by relations, no band (its range depends on the "
                              "operating mode): " + ", ".join(sorted(related_fields)))
    _value_entries(topic, block, periods,
                   frozenset(t.split(" trend:", 1)[0] for t in trends) | related_fields)
    lives = related.liveness.get(topic.name)
    if lives:
        block.comments.extend(liveness_comments(lives))
        block.entries.append(liveness_entry(topic.name, lives))
    return block


def _rate_entries(topic: TopicRecord, block: Block) -> np.ndarray | None:
    series = {p: s.array() for p, s in topic.periods.items()}
    if len(series) <= 1 or len(topic.publishers) <= 1:
        merged = np.concatenate(list(series.values())) if series else np.array([])
        groups: list[tuple[list[str], np.ndarray]] = [([], merged)]
    else:
        groups = [([p], series[p]) for p in sorted(series)]
    first: np.ndarray | None = None
    for group, periods in groups:
        label = f"publisher {group[0]}" if group else "rate"
        if periods.size < MIN_SAMPLES:
            block.notes.append(f"{label}: only {periods.size} periods measured (need "
                               f"{MIN_SAMPLES}): no rate or timeout observer")
            continue
        first = periods if first is None else first
        median = float(np.median(periods))
        p10, p90 = quantile(periods, 0.1), quantile(periods, 0.9)
        if median <= 0 or p10 <= 0 or p90 / p10 > IRREGULAR:
            block.notes.append(f"{label}: irregular arrivals (periods p10 {_s(p10)} s, p90 "
                               f"{_s(p90)} s): event-driven, no rate or timeout observer")
            continue
        longest = float(periods.max())
        floor = max(0.02 * median + 0.0005, RATE_TOLERANCE * median)
        shortest = learn_bounds(periods, floor=floor, max_window=_max_window(periods))
        assert shortest is not None  # periods.size >= MIN_SAMPLES
        bounds = lengthened(periods, shortest, _max_window(periods), floor=floor)
        timeout = max(2 * longest, 5 * median, TIMEOUT_FLOOR)
        block.comments.append(
            f"{label}: {1 / median:.4g} Hz (period p50 {_s(median)} s, p99.9 "
            f"{_s(quantile(periods, 0.999))} s, longest {_s(longest)} s, {periods.size:,} "
            f"periods); hz {_bounds_note(bounds, ' s')}; timeout = max(2 x longest, "
            f"5 x p50, {TIMEOUT_FLOOR:g} s)")
        block.entries.append({"type": "hz", "topic": topic.name, "publishers": group,
                              "filter": _filter(bounds),
                              "states": [{**STATE, "period": _between(bounds.lower,
                                                                      bounds.upper)}]})
        block.entries.append({"type": "timeout", "topic": topic.name, "publishers": group,
                              "timeout": round_up(timeout, 2)})
    return first


def _value_entries(topic: TopicRecord, block: Block, periods: np.ndarray | None,
                   trends: frozenset[str] = frozenset()) -> None:
    if topic.discovery is None:
        if topic.undecodable:
            block.notes.append(f"values not learned: {topic.decode_reason}")
        return
    if topic.discovery.skipped:
        block.comments.append("not numbers, skipped: " + ", ".join(topic.discovery.skipped))
    max_window = _max_window(periods)
    listed: list[str] = []
    quantities: list[dict[str, Any]] = []
    checks: dict[str, Any] = {}
    for rec in topic.fields:
        if rec.problems:
            block.notes.append(f"{rec.info.path} unreadable in {rec.problems} messages "
                               f"({rec.last_problem}): not observed")
            continue
        if rec.info.kind == "stamp":
            _age_entry(topic, rec, block, max_window, listed)
            continue
        summaries = ("value",) if rec.info.kind == "scalar" else ("mean", "min", "max")
        if rec.info.kind != "scalar" and any(t.startswith(f"{rec.info.path}[") for t in trends):
            # elements that climb or are judged by relations: their summaries would leave
            # any band learned in two minutes just the same (issue 22 item 7)
            block.comments.append(f"{rec.info.path}: elements trend or are judged by "
                                  "relations, no band for the array's summaries")
            continue
        kinds = []
        for summary in summaries:
            series = rec.series.get(summary)
            label = rec.info.path if summary == "value" else f"{summary}({rec.info.path})"
            if series is None or len(series) < MIN_SAMPLES:
                block.notes.append(f"{label}: only {0 if series is None else len(series)} "
                                   f"samples (need {MIN_SAMPLES}): not observed")
                continue
            if summary == "value" and rec.info.path in trends:
                continue  # a trend leaves any band it was learned in (issue 22 item 7)
            x = series.array()
            cls = classify(x, rec.info.integer and summary != "mean")
            kinds.append(cls.kind)
            if cls.kind in ("constant", "counter", "monotonic"):
                listed.append(f"{label} {cls.kind}: {cls.note}")
                continue
            name = quantity_name(rec.info.path, "" if summary == "value" else summary)
            if cls.kind == "discrete":
                lo, hi = float(x.min()), float(x.max())
                quantities.append({"name": name, "field": rec.info.path,
                                   **({} if summary == "value" else {"summary": summary})})
                checks[name] = _between(lo - 0.5, hi + 0.5)
                block.comments.append(f"{label} discrete: {cls.note}")
                continue
            b = learn_bounds(x, max_window=max_window)
            assert b is not None
            filt = _filter(b)
            checks[name] = _between(b.lower, b.upper)
            least = least_spread(x, b.window)
            note = ""
            if least is not None:
                filt["deviation"] = "std_deviation"
                checks[name]["deviation"] = [{"type": "greater_than",
                                              "greater_than": round_down(least / 4, 3)}]
                note = (f"; window std >= {_s(least)} (0.1 % quantile) while learning, must "
                        f"stay > a quarter of it (a frozen value)")
            quantities.append({"name": name, "field": rec.info.path,
                               **({} if summary == "value" else {"summary": summary}),
                               "filter": filt})
            block.comments.append(f"{label}: {_bounds_note(b)}{note}")
        if rec.info.kind == "array" and "numeric" in kinds:
            _in_range(rec, max_window, quantities, checks, block)
    if listed:
        block.comments.append("not observed as values: " + "; ".join(listed))
    if quantities:
        block.entries.append({"type": "fields", "topic": topic.name, "fields": quantities,
                              "states": [{**STATE, **checks}]})


def least_spread(x: np.ndarray, window: int) -> float | None:
    """The 0.1 % quantile of the standard deviation of ``window`` consecutive samples, or
    ``None`` when a frozen value cannot be told from the healthy spread (windows under
    ``MIN_STUCK_WINDOW`` samples, or healthy windows that were already frozen)."""
    if window < MIN_STUCK_WINDOW or x.size < window * 10:
        return None
    spread = np.lib.stride_tricks.sliding_window_view(x, window).std(axis=1, ddof=1)
    least = quantile(spread, 0.001)
    return least if least > 0 else None


def _in_range(rec: FieldRecord, max_window: int, quantities: list[dict[str, Any]],
              checks: dict[str, Any], block: Block) -> None:
    finite = rec.series.get("finite")
    if finite is None or len(finite) < MIN_SAMPLES:
        return
    lo, hi = rec.element_low, rec.element_high
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        return
    span = hi - lo
    low, high = round_down(lo - 0.1 * span), round_up(hi + 0.1 * span)
    least = float(finite.array().min())
    threshold = max(0.0, 0.9 * least)
    name = quantity_name(rec.info.path, "in_range")
    window = min(max_window, 5)
    quantities.append({"name": name, "field": rec.info.path, "summary": "in_range",
                       "range": [low, high],
                       "filter": {"type": "mean", "window_size": window} if window > 1
                       else {"type": "nofilter"}})
    checks[name] = {"value": {"type": "greater_than", "greater_than": round_down(threshold, 3)}}
    block.comments.append(f"in_range({rec.info.path}): elements {_s(lo)}..{_s(hi)}, at least "
                          f"{100 * least:.4g} % finite per message; must keep > "
                          f"{100 * threshold:.3g} % inside {_s(low)}..{_s(high)}")


def _age_entry(topic: TopicRecord, rec: FieldRecord, block: Block, max_window: int,
               listed: list[str]) -> None:
    if rec.info.path != "header.stamp":
        listed.append(f"{rec.info.path} time stamp")
        return
    series = rec.series.get("age")
    if series is None or len(series) < MIN_SAMPLES:
        block.notes.append(f"header.stamp: only {0 if series is None else len(series)} "
                           f"non-zero stamps (need {MIN_SAMPLES}): message age not observed")
        return
    b = learn_bounds(series.array(), floor=AGE_FLOOR, max_window=max_window)
    assert b is not None
    block.comments.append(f"message age (receive time - header.stamp): {_bounds_note(b, ' s')}")
    block.entries.append({"type": "timestamp", "topic": topic.name, "publishers": [],
                          "filter": _filter(b),
                          "states": [{**STATE, "age": _between(b.lower, b.upper)}]})

