"""A learned relation between the values of two topics: analytical redundancy, checked.

``blackbox learn`` finds signals that carry the same information (an IMU yaw rate, the
commanded yaw rate, a scan matcher's yaw rate) and writes, per pair of topics, models that
predict a *target* signal of one topic from *inputs* of the other, each input through a
few lagged taps (a linear FIR fit, so different rates and delays line up). This observer
checks them on a common grid of ``step`` seconds:

* every signal is put on the grid ``delay`` seconds late, when the sample after each cell
  has arrived (``blackbox.observe.signals``: the mean of the lines joining its samples);
  a sample is placed at its message's header stamp (``stamps``: topic -> stamp field)
  when that lies within a second of its arrival, else at its arrival (``sample_time``);
* the residual ``target - prediction`` is averaged over blocks of ``block`` grid steps and
  standardised by the healthy block noise; a two-sided CUSUM (drift ``k``, alarm ``h``,
  ``h`` calibrated while learning for a stated false-alarm rate) accumulates it, so a slow
  drift builds up evidence instead of hiding in noise;
* *no excitation, no verdict*: when the prediction moved less than ``excitation`` (standard
  deviation over the last ``window`` seconds), the relation is judged with the noise
  learned standing still if the learning run had such a mode (``still``), else it is
  unjudged; a prediction outside the learned range is not extrapolated; a stale signal
  (nothing for ``fresh`` seconds: killed, stalled, NaN) gives no verdict either;
* signals that move on their own (``track``: a battery's voltage against its current, two
  climbing wheel angles) have a residual bias that moves slowly: it is followed over
  ``track`` seconds, by at most ``track_rate`` a second (bounded by what it did while
  learning), so a fault's offset or drift is not learned as the new normal;
* an input with ``magnitude: true`` enters by its absolute value (a motor or battery
  current follows how fast the robot drives and turns, whichever the direction);
* ``topic_b`` may be ``topic``: a signal related to others of its own topic (the only
  relation it has) accuses that topic's producers alone;
* ``clears: false``: the relation sees a fault of its target but not one of its inputs (a
  clean command beside a noisy sensor); failed, it accuses as any other, held, it clears
  its target alone (every learned relation sees a fault of four noise std on its target:
  a GPS speed that agrees with the command is right, whatever the command's own faults);
* the verdict has three values: failed (CUSUM at ``h``), held (below ``h / 2``), and in
  between, or unjudged, ``NOT_AVAILABLE``: a held relation clears the (topic, field)
  signals it relates in the diagnosis (``judged_signals``, docs/diagnosis.md), so it says
  so only when it is sure; the observer is ``OK`` when every relation that can clear
  holds.

.. code-block:: yaml

    - type: relation
      topic: /cmd_yaw
      topic_b: /imu/data
      step: 0.05
      block: 10
      window: 5.0
      fresh: 0.3
      delay: 0.15
      stamps: {/imu/data: header.stamp}
      relations:
        - name: imu_data_angular_velocity_z
          target: {topic: /imu/data, field: angular_velocity.z}
          inputs:
            - {topic: /cmd_yaw, field: data, lags: [0.0, 0.05, 0.1], gains: [0.2, 0.5, 0.3]}
          intercept: 0.0
          block_noise: 0.008
          cusum: {k: 0.5, h: 11.8}
          excitation: 0.05
          span: [-0.9, 0.9]
"""

from __future__ import annotations

import contextlib
import math
from collections import deque
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

from blackbox.config.node import ConfigNode
from blackbox.events import Interest, MessageArrival
from blackbox.model import Code, Observation, Resource
from blackbox.observe.base import (
    EVIDENCE,
    OBSERVERS,
    JudgedSignals,
    Mode,
    ObserverBase,
    ObserverKind,
    Subject,
)
from blackbox.observe.fieldpath import compile_field_access
from blackbox.observe.observers.entry import COMMON_KEYS, read_every, read_name
from blackbox.observe.observers.timestamp import stamp_seconds
from blackbox.observe.signals import (
    Cusum,
    CusumSpec,
    GridCell,
    GridKey,
    SignalReader,
    SignalRef,
    read_signal_ref,
    sample_time,
)

MAX_GAP = 30.0
"""A gap in time longer than this (seconds) restarts the grid instead of replaying it."""
SEED_BLOCKS = 10
"""Judged blocks a relation that follows a moving bias first spends finding it (unjudged)."""
ANCHOR_BELOW = 2.0
"""The bias from before an alarm is the followed bias of the last block whose CUSUM was
below ``h / ANCHOR_BELOW`` (held). Below ``h / 4`` was tried: a healthy residual's CUSUM
wanders above that for minutes, the old bias was then minutes old when a battery fault
ended, and going back to it raised four false alarms in 30 s (sim:diffdrive seed 3).
Going back only after the CUSUM reached ``h``, not whenever it was undecided: a healthy
residual's CUSUM is undecided now and then, and each time the followed bias went back a
few blocks, so it lagged a discharging battery more and more (three false alarms in the
last minute of a healthy hour of sim:diffdrive)."""
SETTLE_SECONDS = 1.0
"""After an alarm a relation clears again only once it has held this long (:class:`_Judge`)."""

_NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")


@dataclass(frozen=True, slots=True)
class Tap:
    """``gain * signal(t - lag)``, the lag in grid steps; with ``magnitude``,
    ``gain * |signal(t - lag)|`` (a motor current follows the speed's size, not its sign)."""

    signal: SignalRef
    steps: int
    gain: float
    magnitude: bool = False


@dataclass(frozen=True, slots=True)
class NoiseMode:
    """The healthy residual of one operating mode: block mean ``bias`` and ``block_noise``."""

    bias: float
    block_noise: float


@dataclass(frozen=True, slots=True)
class RelationSpec:
    """One learned model: ``target`` predicted by ``taps`` plus ``intercept``."""

    name: str
    target: SignalRef
    target_steps: int
    taps: tuple[Tap, ...]
    intercept: float
    moving: NoiseMode
    still: NoiseMode | None
    cusum: CusumSpec
    excitation: float
    span: tuple[float, float]
    clears: bool = True
    """Whether holding is evidence of its inputs' health (false: it cannot see their
    faults, and clears its target alone)."""
    track_rate: float = math.inf
    """The most the followed bias moves per second."""
    track: float | None = None
    """Seconds over which a moving bias of the residual is followed (signals that move on
    their own), ``None``: the learned bias is fixed."""

    def inputs(self) -> str:
        return ", ".join(dict.fromkeys(f"|{t.signal.label()}|" if t.magnitude
                                       else t.signal.label() for t in self.taps))


class _Judge:
    """The running test of one relation."""

    __slots__ = ("alpha", "anchor", "count", "cusum", "doubt", "excite", "followed",
                 "in_alarm", "last_z", "pred_sum", "reason", "res_sum", "seeded", "settle",
                 "spec", "step_limit", "unjudged_blocks", "verdict")

    def __init__(self, spec: RelationSpec, window_blocks: int, block_seconds: float) -> None:
        self.spec = spec
        self.alpha = 0.0 if spec.track is None else min(1.0, block_seconds / spec.track)
        self.step_limit = spec.track_rate * block_seconds
        self.followed = 0.0
        self.anchor = 0.0
        """The followed bias from before the current alarm (see :meth:`_follow`)."""
        self.in_alarm = False
        """The CUSUM reached ``h`` and has not been back under ``h / 2`` since."""
        self.settle = max(1, math.ceil(SETTLE_SECONDS / block_seconds - 1e-9))
        self.doubt = 0
        """Held blocks still to come before a relation that failed clears again."""
        self.seeded = 0
        self.cusum = Cusum(spec.cusum)
        self.excite: deque[float] = deque(maxlen=window_blocks)
        self.res_sum = 0.0
        self.pred_sum = 0.0
        self.count = 0
        self.last_z = math.nan
        self.verdict = "unjudged"
        self.reason = "waiting for data"
        self.unjudged_blocks = 0

    def reset(self, reason: str) -> None:
        self.cusum.reset()
        self.in_alarm = False
        self.doubt = 0
        self.excite.clear()
        self.res_sum = self.pred_sum = 0.0
        self.count = 0
        self.verdict = "unjudged"
        self.reason = reason

    def end_block(self, block: int, window_blocks: int) -> None:
        spec, count = self.spec, self.count
        residual = self.res_sum / count if count else math.nan
        predicted = self.pred_sum / count if count else math.nan
        self.res_sum = self.pred_sum = 0.0
        self.count = 0
        if count * 2 < block:
            self._unjudged(self.reason if self.reason.startswith("stale") else
                           "waiting for fresh samples of every signal", window_blocks)
            return
        self.excite.append(predicted)
        if len(self.excite) < self.excite.maxlen:  # type: ignore[operator]
            self._unjudged(f"waiting for {window_blocks} blocks to judge excitation",
                           window_blocks)
            return
        lo, hi = spec.span
        if not lo <= predicted <= hi:
            self._unjudged(f"prediction {predicted:.4g} outside the learned range "
                           f"{lo:.4g}..{hi:.4g}: not extrapolated", window_blocks)
            return
        spread = _std(self.excite)
        mode = spec.moving
        if spread < spec.excitation:
            if spec.still is None:
                self._unjudged(f"no excitation: the prediction moved {spread:.3g} (std over "
                               f"{window_blocks} blocks), need {spec.excitation:.3g}; "
                               "standing still was not seen while learning", window_blocks)
                return
            mode = spec.still
        self.unjudged_blocks = 0
        if self.alpha and self.seeded < SEED_BLOCKS:
            # A followed bias has no level to start from: the trend (a discharging battery)
            # went on between learning and this run. It starts at the mean offset of the
            # run's first SEED_BLOCKS judged blocks, not at the learning run's mean (that
            # start, 1-2 block noise away, was a false alarm in the first minute of every
            # healthy run of the real diffdrive robots; one block's offset, a block noise
            # off itself, raised five more false positives in three sim:skidsteer runs).
            # Once per run: after a restart of the grid a fault may be on.
            self.seeded += 1
            self.followed += (residual - mode.bias - self.followed) / self.seeded
            self._unjudged(f"finding where its moving bias is now ({self.seeded} of "
                           f"{SEED_BLOCKS} blocks)", window_blocks)
            return
        off = self._follow(residual - mode.bias, mode.block_noise)
        self.last_z = off / mode.block_noise
        if self.alpha:  # at a bounded rate: a fault's offset or drift is not followed
            self.followed += min(self.step_limit, max(-self.step_limit, self.alpha * off))
        stat = self.cusum.update(self.last_z)
        if stat >= spec.cusum.h:
            self.in_alarm = True
        elif stat < spec.cusum.h / ANCHOR_BELOW:
            self.in_alarm = False
            self.anchor = self.followed
        h = spec.cusum.h
        self.verdict = "failed" if stat >= h else "undecided" if stat >= h / 2 else "held"
        # An alarm ends in doubt: a relation that failed clears its signals again only
        # once it has held for SETTLE_SECONDS (a verdict's interval). Its recovery takes
        # the CUSUM to h/2 with one healthy-looking block, and the next can be under h/2:
        # held and clearing one verdict after failing, while a slower relation of the
        # same target (a GPS speed against a 1 Hz odometer) still sees the fault's last
        # second and so names its other signal (sim:skidsteer, round rel22b).
        if self.verdict == "failed":
            self.doubt = self.settle
        elif self.verdict == "held" and self.doubt > 0:
            self.doubt -= 1
            self.verdict = "undecided"
        self.reason = ""

    def _follow(self, residual: float, noise: float) -> float:
        """The residual less the followed bias; in an alarm, less the bias from before it
        when that one explains the block better and calmly.

        The followed bias moves during a fault (at its bounded rate: a few seconds of an
        offset move it by a block noise or more), so when the fault ends the residual
        sits that far off the followed bias, on the other side, and the relation failed
        on for the 8-38 s the bias took to come back (issue 22: most false alarms of the
        real diffdrive robots' campaigns, a battery voltage ~ current relation after a
        battery fault). Freezing the bias in an alarm was worse: it could then not follow
        a real slow change and the alarm never ended. So the bias goes on moving, and the
        one from before the alarm is kept beside it: once the residual agrees with that
        one again (a block the CUSUM's recovery would take as healthy, judged against the
        old bias), the signals agree as they did before the fault, and the followed bias
        goes back to it. A fault still on does not agree with the old bias (it is what
        raised the alarm); a real slow change during a long alarm leaves the residual off
        the old bias too, and the followed one goes on following it."""
        off = residual - self.followed
        if not self.alpha or not self.in_alarm:
            return off
        old = residual - self.anchor
        if abs(old) < abs(off) and self.cusum.calm(old / noise):
            self.followed = self.anchor
            return old
        return off

    def _unjudged(self, reason: str, window_blocks: int) -> None:
        self.verdict = "unjudged"
        self.reason = reason
        # An alarm does not outlive a blind spell: unjudged (no excitation, a stale or
        # unextrapolated signal), a relation in alarm is undecided when it is judged
        # again, and a fault still on needs another h/2 of evidence. Kept at h, a
        # relation that was unjudged for the last seconds of a fault failed again on its
        # first block after them, whatever that block said (an IMU scale that ended while
        # the robot stood still: a false alarm naming the IMU 3 s after; sim:diffdrive)
        if self.cusum.alarm:
            self.cusum.doubt()
        self.unjudged_blocks += 1
        if self.unjudged_blocks >= window_blocks:
            self.cusum.reset()  # old evidence does not carry over a long blind spell
            self.in_alarm = False


def _std(values: deque[float]) -> float:
    n = len(values)
    mean = sum(values) / n
    return math.sqrt(max(0.0, sum((v - mean) ** 2 for v in values) / n))


class RelationObserver(ObserverBase):
    """Learned relations between signals of ``topic`` and ``topic_b`` (docs/learn.md)."""

    type_name: ClassVar[str] = "relation"

    def __init__(self, topic: str, topic_b: str, relations: Sequence[RelationSpec], *,
                 step: float, block: int, window: float, fresh: float,
                 delay: float | None = None, every: float = 1.0,
                 stamps: Mapping[str, str] | None = None) -> None:
        if not relations:
            raise ValueError("a relation observer needs at least one relation")
        self.stamps = dict(stamps or {})
        self._stamps = {topic: compile_field_access(path) for topic, path in self.stamps.items()}
        self.topic, self.topic_b = topic, topic_b
        self.resource = Resource(topic=topic, topic_b=topic_b)
        self.interval = every
        self.step, self.block, self.window, self.fresh = step, block, window, fresh
        self.window_blocks = max(2, round(window / (step * block)))
        self.relations = tuple(relations)
        refs = {r.target: None for r in relations}
        for r in relations:
            refs.update({t.signal: None for t in r.taps})
        self._refs = tuple(refs)
        self._readers = {ref: SignalReader(ref) for ref in self._refs}
        self.delay = fresh if delay is None else delay
        self._cells = {ref: GridCell(fresh, step, self.delay) for ref in self._refs}
        depth = 1 + max(max((t.steps for r in relations for t in r.taps), default=0),
                        max(r.target_steps for r in relations))
        self._history = {ref: deque([math.nan] * depth, maxlen=depth) for ref in self._refs}
        self._judges = [_Judge(r, self.window_blocks, step * block) for r in relations]
        self._wire(self._refs)
        self._next: float | None = None
        self._ticks = 0
        self._phased = False
        """Whether the blocks are phased to end at verdicts (:meth:`_phase`)."""
        self._undecodable: dict[str, int] = {}
        """Messages per topic since the last evaluation that gave no value to read."""

    def _wire(self, feeds: Collection[SignalRef]) -> None:
        """Which cells each topic's messages feed (those of ``feeds``; another observer
        feeds the rest) and what a tick reads and writes, from the cells and histories."""
        self._by_topic: dict[str, list[tuple[SignalReader, GridCell]]] = {
            ref.topic: [] for ref in self._refs}
        for ref in self._refs:
            if ref in feeds:
                self._by_topic[ref.topic].append((self._readers[ref], self._cells[ref]))
        self._fed = [self._cells[ref] for ref in self._refs if ref in feeds]
        """The cells this observer feeds and resets."""
        history = self._history
        self._closing = [(cell.close, history[ref].appendleft)
                         for ref, cell in self._cells.items()]
        self._predicting = [
            (judge, history[j.target], j.target_steps, j.intercept,
             [(history[t.signal], t.steps, t.gain, t.magnitude) for t in j.taps])
            for judge, j in zip(self._judges, self.relations, strict=True)]
        """Per relation the histories it reads, resolved once (a tick runs 20 times a
        second per observer, and a dictionary look-up per tap per tick showed in profiles)."""

    def grid_keys(self) -> dict[SignalRef, GridKey]:
        """What makes each signal's cell (``signals.share_cells``)."""
        return {ref: GridKey(ref, self.stamps.get(ref.topic), self.fresh, self.step,
                             self.delay) for ref in self._refs}

    def use_cells(self, cells: Mapping[SignalRef, GridCell], fed: Collection[SignalRef]
                  ) -> None:
        """Read ``cells`` instead of cells of its own; feed only those in ``fed`` (another
        observer feeds the rest, from the same messages)."""
        own = self._cells
        self._cells = {ref: cells.get(ref, own[ref]) for ref in self._refs}
        self._wire({ref for ref in self._refs if ref not in cells or ref in fed})

    def interest(self) -> Interest:
        """The topics whose cells it feeds: a topic whose cells another observer feeds
        (:meth:`use_cells`) needs no message here; the grid advances on the others and at
        every evaluation, and reads the shared cells' closed points."""
        return Interest(decoded=frozenset(t for t, feeds in self._by_topic.items() if feeds))

    def quantity_names(self) -> tuple[str, ...]:
        return tuple(n for r in self.relations
                     for n in (f"{r.name}_z", f"{r.name}_cusum", f"{r.name}{EVIDENCE}"))

    # ---- the grid ------------------------------------------------------------------------------

    def _advance(self, t: float) -> None:
        nxt = self._next
        if nxt is None:
            # the grid starts at the first sample of its signals, which is this message's
            # unless another observer fed a shared cell first (use_cells)
            first = min((cell.first_time for cell in self._cells.values()), default=t)
            nxt = math.ceil(min(first, t) / self.step) * self.step
            if nxt >= t:
                self._next = nxt
                return
        if t - nxt > MAX_GAP:
            self._restart(t, f"no message for {t - nxt:.0f} s: restarted")
            return
        while nxt < t:
            self._tick(nxt)
            nxt += self.step
        self._next = nxt

    def _restart(self, t: float, why: str) -> None:
        for cell in self._fed:
            cell.reset()
        for hist in self._history.values():
            hist.extend([math.nan] * (hist.maxlen or 1))
        for judge in self._judges:
            judge.reset(why)
        self._ticks = 0
        self._phased = False
        self._next = math.ceil(t / self.step) * self.step

    def _tick(self, g: float) -> None:
        for close, append in self._closing:
            append(close(g))
        for judge, target, target_steps, predicted, taps in self._predicting:
            y = target[target_steps]
            for signal, steps, gain, magnitude in taps:
                x = signal[steps]
                predicted += gain * (abs(x) if magnitude else x)
            if y != y or predicted != predicted:  # NaN
                spec, history = judge.spec, self._history
                stale = [ref.label() for ref in (spec.target, *(t.signal for t in spec.taps))
                         if math.isnan(history[ref][0])]
                if stale:
                    judge.reason = (f"stale: no fresh sample of {', '.join(dict.fromkeys(stale))}"
                                    f" within {self.fresh:g} s")
                continue
            judge.res_sum += y - predicted
            judge.pred_sum += predicted
            judge.count += 1
        self._ticks += 1
        if self._ticks % self.block == 0:
            for judge in self._judges:
                judge.end_block(self.block, self.window_blocks)

    # ---- events ---------------------------------------------------------------------------------

    def on_message(self, msg: MessageArrival) -> None:
        pairs = self._by_topic.get(msg.topic)
        if pairs is None:
            return
        nxt = self._next
        if nxt is None or msg.time > nxt:  # else no grid point passed: nothing to tick
            self._advance(msg.time)
        try:
            value = msg.value
        except Exception:  # the robot's garbage, never the black box's crash
            value = None
        if value is None:
            self._undecodable[msg.topic] = self._undecodable.get(msg.topic, 0) + 1
            return
        if not pairs:  # another observer feeds this topic's cells
            return
        t = msg.time
        stamp = self._stamps.get(msg.topic) if self._stamps else None
        if stamp is not None:
            memo = msg.memo
            key = ("time", self.stamps[msg.topic])
            t = memo.get(key, math.nan)
            if t != t:  # NaN: not derived yet
                t = msg.time
                with contextlib.suppress(ValueError):  # no stamp: its arrival times it
                    t = sample_time(t, stamp_seconds(stamp(value)))
                memo[key] = t
        for reader, cell in pairs:
            x = reader.read_arrival(msg, value)
            if x is not None:
                cell.add(t, x)

    def _phase(self) -> None:
        """Blocks end at verdicts: at the first verdict after the grid started (and the
        first after a restart) the block begun so far is dropped, so every block from then
        on ends at the last grid point before a verdict when its length divides the
        verdict interval (0.5 s and 1 s blocks, verdicts each second). Phased from the
        first message instead, a block ended anywhere up to a block before the verdict
        that reported it: a 1 s block of a 1 Hz odometer's relation judged data up to a
        second staler than it had, and its alarm outlived a GPS fault's end by 2-3 s,
        beyond the 2 s grace, naming the odometer (sim:skidsteer, round rel22b)."""
        for judge in self._judges:
            judge.res_sum = judge.pred_sum = 0.0
            judge.count = 0
        self._ticks = 0
        self._phased = True

    def evaluate(self, now: float) -> list[Observation]:
        self._advance(now)
        if not self._phased and self._next is not None:
            self._phase()
        values: dict[str, float] = {}
        failed: list[str] = []
        held: list[str] = []
        open_: list[str] = []
        open_all: list[str | None] = []
        for judge in self._judges:
            spec = judge.spec
            stat = judge.cusum.statistic
            if judge.verdict != "unjudged":
                values[f"{spec.name}_z"] = round(judge.last_z, 4)
                values[f"{spec.name}_cusum"] = round(stat, 4)
                values[f"{spec.name}{EVIDENCE}"] = round(stat / spec.cusum.h, 4)
            what = f"{spec.target.label()} ~ {spec.inputs()}"
            open_all.append(None)
            if judge.verdict == "failed":
                failed.append(f"{spec.target.label()} disagrees with {spec.inputs()} "
                              f"(residual {judge.last_z:+.1f} noise std, CUSUM {stat:.1f} >= "
                              f"{spec.cusum.h:.1f})")
            elif judge.verdict == "held" and not spec.clears:
                held.append(f"{what} (CUSUM {stat:.1f} < {spec.cusum.h / 2:.1f}; cannot see "
                            f"its inputs' faults, clears {spec.target.label()} alone)")
            elif judge.verdict == "held":
                held.append(f"{what} (CUSUM {stat:.1f} < {spec.cusum.h / 2:.1f})")
            elif judge.verdict == "undecided" and stat < spec.cusum.h / 2:
                open_.append(f"{what}: undecided, settling after an alarm (CUSUM {stat:.1f} "
                             f"< {spec.cusum.h / 2:.1f} for less than {SETTLE_SECONDS:g} s)")
                open_all[-1] = open_[-1]
            elif judge.verdict == "undecided":
                open_.append(f"{what}: undecided (CUSUM {stat:.1f} between "
                             f"{spec.cusum.h / 2:.1f} and {spec.cusum.h:.1f})")
                open_all[-1] = open_[-1]
            else:
                open_.append(f"{what}: unjudged, {judge.reason}")
                open_all[-1] = open_[-1]
        undecoded = self._undecoded(values)
        if failed:
            text = "; ".join(failed)
            if held:
                text += "; held: " + "; ".join(held)
            text += undecoded
            return [Observation(now, self.type_name, self.resource, Code.NO_STATE_FITS,
                                values=values, message=text)]
        # OK clears the signals judged_signals names: every relation's target, and its
        # inputs when it sees their faults; it needs every relation held
        blocking = [o for o in open_all if o is not None]
        if blocking or not held:
            return [self.unavailable(now, "; ".join(open_ + held) + undecoded, values)]
        text = "holds: " + "; ".join(held)
        if open_:
            text += "; not counted: " + "; ".join(open_)
        text += undecoded
        return [Observation(now, self.type_name, self.resource, Code.GENERAL_OK,
                            values=values, message=text)]

    def _undecoded(self, values: dict[str, float]) -> str:
        """The messages since the last evaluation that did not decode, said as a clause of
        the observation's message and counted in ``values["undecodable"]`` (as the other
        observers report messages they skip); counted afresh from here."""
        counts, self._undecodable = self._undecodable, {}
        if not counts:
            return ""
        values["undecodable"] = float(sum(counts.values()))
        return "; " + ", ".join(f"{n} messages of {topic}" for topic, n in sorted(
            counts.items())) + " did not decode since the last evaluation"

    def judged_signals(self) -> JudgedSignals:
        """Field-level diagnosis (docs/diagnosis.md): a failure accuses the signals of every
        relation; OK clears every relation's target, and the inputs of those that see their
        inputs' faults."""
        accused = {s: None for r in self.relations
                   for s in (r.target, *(t.signal for t in r.taps))}
        cleared = {s: None for r in self.relations
                   for s in ((r.target, *(t.signal for t in r.taps)) if r.clears
                             else (r.target,))}
        return JudgedSignals(tuple((s.topic, s.field) for s in accused),
                             tuple((s.topic, s.field) for s in cleared))

    def describe(self) -> str:
        parts = [f"{r.name}: {r.target.label()} from {r.inputs()} (CUSUM k {r.cusum.k:g}, "
                 f"h {r.cusum.h:g})" for r in self.relations]
        return (f"relation {self.topic} <-> {self.topic_b}: {'; '.join(parts)}; grid "
                f"{self.step:g} s, blocks of {self.block}, every {self.interval:g} s")


# ---- configuration ------------------------------------------------------------------------------

def _mode(node: ConfigNode) -> NoiseMode:
    node.check_keys(("bias", "block_noise"))
    bias = node.get("bias")
    return NoiseMode(0.0 if bias is None else bias.float(),
                     node["block_noise"].float(min=0.0, min_exclusive=True))


def _steps(node: ConfigNode, step: float) -> int:
    lag = node.float(min=0.0, max=60.0)
    steps = round(lag / step)
    if abs(steps * step - lag) > 1e-6 * max(1.0, lag):
        raise node.error(f"lag {lag:g} s is not a multiple of the grid step {step:g} s")
    return steps


def _relation(node: ConfigNode, step: float, topics: tuple[str, str],
              names: set[str]) -> RelationSpec:
    node.check_keys(("name", "target", "target_lag", "inputs", "intercept", "block_noise",
                     "bias", "still", "cusum", "excitation", "span", "fit", "track",
                     "track_rate", "clears"))
    name_node = node["name"]
    name = name_node.str()
    if not name or not set(name) <= _NAME_CHARS or name[0].isdigit():
        raise name_node.error(f"relation name {name!r} must be letters, digits and '_', not "
                              "starting with a digit")
    if name in names:
        raise name_node.error(f"relation {name!r} named twice")
    names.add(name)
    target = read_signal_ref(node["target"])
    if target.topic not in topics:
        raise node["target"]["topic"].error(f"target topic {target.topic!r} is neither "
                                            f"{topics[0]!r} nor {topics[1]!r}")
    lag_node = node.get("target_lag")
    target_steps = 0 if lag_node is None else _steps(lag_node, step)
    taps: list[Tap] = []
    inputs = node["inputs"].list()
    if not inputs:
        raise node["inputs"].error("a relation needs at least one input")
    for item in inputs:
        item.check_keys(("topic", "field", "lags", "gains", "magnitude"))
        ref = read_signal_ref(ConfigNode.mapping({"topic": item["topic"],
                                                 "field": item["field"]}, item))
        if ref.topic not in topics:
            raise item["topic"].error(f"input topic {ref.topic!r} is neither {topics[0]!r} "
                                      f"nor {topics[1]!r}")
        lags, gains = item["lags"].list(), item["gains"].list()
        if not lags or len(lags) != len(gains):
            raise item["gains"].error(f"lags and gains must be lists of one length, got "
                                      f"{len(lags)} and {len(gains)}")
        magnitude = item["magnitude"].bool() if item.get("magnitude") is not None else False
        taps.extend(Tap(ref, _steps(lag, step), gain.float(), magnitude)
                    for lag, gain in zip(lags, gains, strict=True))
    span_node = node["span"]
    span = span_node.list()
    if len(span) != 2 or not span[0].float() <= span[1].float():
        raise span_node.error("span must be [low, high] with low <= high")
    bias = node.get("bias")
    moving = NoiseMode(0.0 if bias is None else bias.float(),
                       node["block_noise"].float(min=0.0, min_exclusive=True))
    still = node.get("still")
    return RelationSpec(
        name=name, target=target, target_steps=target_steps, taps=tuple(taps),
        intercept=node["intercept"].float() if node.get("intercept") is not None else 0.0,
        moving=moving, still=None if still is None or still.is_null else _mode(still),
        cusum=CusumSpec.read(node["cusum"]),
        excitation=node["excitation"].float(min=0.0) if node.get("excitation") else 0.0,
        span=(span[0].float(), span[1].float()),
        track=(node["track"].float(min=0.0, min_exclusive=True)
               if node.get("track") is not None else None),
        track_rate=(node["track_rate"].float(min=0.0)
                    if node.get("track_rate") is not None else math.inf),
        clears=node["clears"].bool() if node.get("clears") is not None else True)


def relation_from_config(node: ConfigNode) -> RelationObserver:
    node.check_keys((*COMMON_KEYS, "topic", "topic_b", "step", "block", "window", "fresh",
                     "delay", "stamps", "relations"))
    topic, topic_b = read_name(node, "topic"), read_name(node, "topic_b")
    step = node["step"].float(min=0.001, max=10.0) if node.get("step") else 0.05
    block = node["block"].int(min=1, max=10_000) if node.get("block") else 10
    window = node["window"].float(min=0.0, min_exclusive=True) if node.get("window") else 5.0
    fresh = node["fresh"].float(min=0.0, min_exclusive=True) if node.get("fresh") else 0.5
    delay_node = node.get("delay")
    delay = (delay_node.float(min=step / 2, max=60.0) if delay_node is not None
             else max(fresh, step / 2))
    names: set[str] = set()
    items = node["relations"].list()
    if not items:
        raise node["relations"].error("relations lists no relation")
    relations = [_relation(item, step, (topic, topic_b), names) for item in items]
    stamps: dict[str, str] = {}
    if node.get("stamps") is not None:
        for name, path in node["stamps"].items():
            if name not in (topic, topic_b):
                raise path.error(f"{name} is neither topic nor topic_b")
            stamps[name] = path.str()
    return RelationObserver(topic, topic_b, relations, step=step, block=block, window=window,
                            fresh=fresh, delay=delay, every=read_every(node), stamps=stamps)


OBSERVERS.add("relation", ObserverKind("relation", relation_from_config, Subject.TOPIC_PAIR,
                                       (), judges=Mode.RIGHT, relation=True), example={
    "type": "relation", "topic": "/cmd_vel", "topic_b": "/odom", "step": 0.05, "block": 10,
    "window": 1.0, "fresh": 2.0,
    "relations": [{"name": "odom_twist_twist_linear_x",
                   "target": {"topic": "/odom", "field": "twist.twist.linear.x"},
                   "target_lag": 0.05,
                   "inputs": [{"topic": "/cmd_vel", "field": "linear.x",
                               "lags": [0.0, 0.05, 0.1], "gains": [0.31, 0.354, 0.337]}],
                   "intercept": 0.0, "bias": 0.0, "block_noise": 0.0069, "still": None,
                   "cusum": {"k": 0.5, "h": 12.6}, "excitation": 1e-6, "span": [-10.0, 10.0]}]})
