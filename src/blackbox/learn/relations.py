"""Learning which signals carry the same information, and how alive each signal is.

From the time-stamped samples of a healthy run (``blackbox.learn.timed``):

1. **Signals.** Every numeric scalar field and element of a short array is a signal, unless
   it is constant, a counter or discrete (``classify``), too short, a *trend*
   (a straight line over time explains most of it: a discharging battery, a warming motor;
   it would leave any band it was learned in) or an angle that wraps (no linear relation
   holds across the wrap). A monotonic field (an odometer) is a trend, related only as an
   input, on its changes (its level carries every past error of the count: an odometer
   predicted from wheel angles raised two or three false alarms in a healthy half hour).
2. **Grid.** All signals are resampled on one grid of ``STEP`` seconds (the mean over each
   cell of the lines joining the samples, ``window_means``), so different rates line up
   without a phase that changes from run to run.
3. **Relations.** For each target signal and each other topic, the lag (within
   ``MAX_LAG``) at which a signal of that topic correlates best with the target is found
   over the whole run; the target is then fitted from that signal through ``TAPS`` lagged
   taps (a short FIR filter, so a delay or a smoothing on the way is modelled), or from up
   to four signals of that topic together when none alone suffices (two wheel speeds and a
   forward speed) or when together they leave at most half of what the best one alone
   leaves unexplained (``prefer_joint``: a wheel speed from the forward and yaw commands).
   Ridge regularisation is chosen by the R² on the last 30 % of the run
   (held out, forward in time), and a relation is kept when its five-fold out-of-fold R²
   over the whole run is at least ``R2_MIN``
   and a fault of four noise std on any of its signals moves the residual by at least
   ``SENSITIVITY`` block noise (a relation that cannot see a signal must not vouch for it).
   Of the two directions of a pair the one with the cleaner input is kept (least squares
   attenuates a noisy input's gain).
4. **Residual noise** comes from out-of-fold predictions (five contiguous folds), averaged
   over blocks of ``BLOCK`` grid steps, or of the slowest signal's period when it is
   slower (``block_for``: a 1 Hz battery gets one-second blocks, one new sample each); the
   CUSUM threshold is calibrated on them (``blackbox.learn.sequential``) for
   ``FALSE_ALARMS_PER_HOUR`` over all checks. A relation whose slowest signal gave fewer
   than ``FEW_SAMPLES`` samples (two minutes of a 1 Hz topic: 120) has its block noise
   widened by the uncertainty of so small a sample (``widening``); under
   ``MIN_RELATION_SAMPLES`` it is not learned.
5. **Modes.** Blocks where the prediction moved less than ``EXCITATION`` block noise (std
   over ``WINDOW`` seconds) are *standing still*: with at least ``MIN_STILL_BLOCKS`` of
   them, standing still gets its own noise and is judged; otherwise the relation is
   unjudged while the robot stands still (no excitation, no verdict).
6. **Liveness** per signal: the longest run of equal samples and the log of the mean
   squared second difference of consecutive samples per block (stuck values, noise
   bursts; a second difference cancels smooth motion, so turning is not a noise burst).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from blackbox.learn.fields import classify
from blackbox.learn.recording import Recording
from blackbox.learn.sequential import Calibration, K, calibrate
from blackbox.learn.stats import round_down, round_up
from blackbox.observe.signals import SignalRef

STEP = 0.05
BLOCK = 10
WINDOW = 5.0
MAX_LAG = 1.0
TAPS = 3
R2_MIN = 0.8
SCREEN = 0.6
"""Smallest correlation (at the best lag) worth fitting a single-input relation for."""
MAX_JOINT = 4
MAX_PEERS = 4
"""Relations kept per target signal (the best by held-out R²)."""
SENSITIVITY = 1.5
EXCITATION = 3.0
MIN_STILL_BLOCKS = 40
FALSE_ALARMS_PER_HOUR = 0.1
K_MAX = 1.25
"""The largest CUSUM drift of a relation (``relation_drift``)."""
MIN_SIGNAL_SAMPLES = 40
"""Samples below which a field is no signal at all (neither related nor checked alive)."""
MIN_GRID_BLOCKS = 60
MIN_RELATION_SAMPLES = 60
"""Samples of a signal while learning below which it is not related (a minute of a 1 Hz
topic): too few to fit, let alone to calibrate a threshold."""
FEW_SAMPLES = 300
"""Samples of a relation's slowest signal below which its block noise is an estimate from
few, dependent blocks: it is widened by its own uncertainty (:func:`widening`)."""
WIDEN_Z = 2.33
"""The block noise of a relation learned from few samples is taken at the upper end of a
one-sided 99 % interval of its estimate."""
TRACK = 2.5
"""Seconds over which a relation of trending signals follows its residual's bias. Short:
exponential smoothing lags a steady discharge by its rate times this (at 20 s the lag
was half a block noise, and a two-hour healthy run raised 185 alarms); the bias's rate
is bounded (``TRACK_RATE``), so a fault is still not followed."""
TRACK_RATE = 5.0
"""The followed bias may move this many times as fast as it did while learning."""
CHANGE_STEPS = 100
"""Grid steps over which a trending signal's change is taken (five seconds)."""
LIVENESS_BLOCK_SECONDS = 0.5
LIVE_BLOCKS = 40
"""Blocks of second differences a noise check is learned from; with fewer (a 1 Hz signal
for two minutes), blocks of ``SLOW_LIVE_BLOCK`` samples, at least ``MIN_LIVE_BLOCKS`` of
them, their spread widened for the small sample (``widening``)."""
SLOW_LIVE_BLOCK = 3
MIN_LIVE_BLOCKS = 30
NOISE_CAP = 25.0
"""A squared second difference counts at most this many times the healthy mean squared
second difference in a noise check's blocks, while learning and while judging. A step (a
value going back when an offset or scale fault ends) is one large first difference and
so two large second differences: uncapped, those two lifted a block by ten standard
deviations and raised a noise burst after the fault had ended. A Gaussian healthy value
exceeds the cap once in a million samples; a burst of three times the noise is many
differences, most under the cap, and still lifts every block (by 2.1 of the log instead
of 2.3)."""
NOISE_SHIFT = math.log(10.0)
"""What a noise burst of three times a signal's noise std adds to the log of its mean
squared second difference (the mean square grows 1 + 3² times)."""


def noise_drift(std: float) -> float:
    """The CUSUM drift ``k`` of a noise check whose block log mean square has spread
    ``std``: half the shift of the smallest burst it is for (``NOISE_SHIFT``, in standard
    units), at least ``K``. A drift of half a standard unit summed every mild, sustained
    rise of the second differences (a wheel angle at 50 Hz in a harder stretch of driving
    than the two minutes learned: +1.7 to +2.1 std for a minute, two false alarms in a
    healthy half hour of sim:skidsteer learned from seed 101), while a burst moves the
    statistic by several."""
    return round(max(K, NOISE_SHIFT / (2.0 * std)), 3) if std > 0 else K


LOGGING_TOPICS = frozenset({"/rosout", "/rosout_agg"})
LAMBDAS = (0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)


@dataclass
class Signal:
    ref: SignalRef
    name: str
    times: np.ndarray
    values: np.ndarray
    period: float
    noise: float
    """Per-sample noise: robust std of consecutive differences / sqrt(2)."""
    wrap: bool
    trend: float | None
    """Slope per second when a straight line explains the signal (a trend), else None."""
    integer: bool
    grid: np.ndarray = field(default_factory=lambda: np.empty(0))
    drift: float | None = None
    """Slope per second of what the signal does on its own beside the other signals of its
    topic, when it is significant and would leave the learned range within an hour (a
    battery voltage discharging under a current that moves it more): no band."""
    note: str = ""
    monotonic: bool = False
    """Only grows or only falls (an odometer): related as an input on its changes, never on
    its level nor as a target (its level carries every past error of the count)."""
    stamp: str | None = None
    """Its topic's header stamp, which times its samples (``sample_time``)."""
    magnitude: bool = False
    """An input by its absolute value (``grid`` holds it): :func:`magnitudes_of`."""


@dataclass
class Relation:
    target: Signal
    inputs: list[tuple[Signal, list[int]]]
    """Each input with its tap lags in grid steps (relative to the target, may be < 0)."""
    gains: list[list[float]]
    intercept: float
    target_steps: int
    r2: float
    noise: float
    moving: tuple[float, float]
    still: tuple[float, float] | None
    excitation: float
    span: tuple[float, float]
    z: np.ndarray
    sensitivity: float
    calibration: Calibration | None = None
    clears: bool = True
    """Whether a held verdict is evidence of health (it sees a fault of four noise std on
    every one of its signals)."""
    track: float | None = None
    """Seconds over which the observer follows a slowly moving bias of the residual (a
    relation of signals that move on their own: a discharging battery's voltage against
    its current, two climbing wheel angles), ``None`` for a fixed bias."""
    track_rate: float | None = None
    """The most the followed bias moves per second (residual units)."""
    on_changes: tuple[str, ...] = ()
    """Labels of trending inputs related on their changes, not their level."""
    block: int = BLOCK
    """Grid steps per residual block (:func:`block_for`)."""
    widen: float = 1.0
    """The factor its block noise was widened by for few samples (:func:`widening`)."""

    @property
    def topics(self) -> tuple[str, str]:
        a, b = self.target.ref.topic, self.inputs[0][0].ref.topic
        return (a, b) if a < b else (b, a)


@dataclass
class Liveness:
    signal: Signal
    repeats: int | None
    longest_run: int
    block: int
    mean: float
    std: float
    z: np.ndarray | None
    calibration: Calibration | None = None
    rate: float | None = None
    """For a signal that climbs (a trend): the most it may change per second between
    consecutive samples (:func:`rate_bound`), else ``None``."""
    fastest: float = 0.0
    """The fastest change per second seen while learning."""
    cap: float | None = None
    """The most one squared second difference counts in a noise block (``NOISE_CAP``)."""


@dataclass
class RelationsLearned:
    relations: list[Relation]
    liveness: dict[str, list[Liveness]]
    trends: dict[str, list[str]]
    """topic -> comment per trend signal (their envelopes are not written)."""
    notes: list[str]
    signals: int = 0
    related: dict[str, set[str]] = field(default_factory=dict)
    """topic -> fields judged by a relation (their envelopes are not written: two minutes
    of learning cannot know the operating range, a relation does not need it)."""



# ---- signals ------------------------------------------------------------------------------------

def _wrapped(d: np.ndarray) -> np.ndarray:
    return (d + math.pi) % (2 * math.pi) - math.pi


def _robust(x: np.ndarray) -> float:
    if x.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def signals_of(rec: Recording, notes: list[str]) -> list[Signal]:
    out: list[Signal] = []
    for topic in sorted(rec.topics.values(), key=lambda t: t.name):
        if topic.name in LOGGING_TOPICS:
            continue
        for frec in topic.fields:
            if frec.info.kind == "stamp" or frec.problems:
                continue
            for key, series in sorted(frec.timed.items()):
                path = frec.info.path if key == "value" else f"{frec.info.path}{key}"
                t, x = series.arrays()
                if x.size < MIN_SIGNAL_SAMPLES:
                    continue
                kind = classify(x, frec.info.integer).kind
                if kind not in ("numeric", "monotonic"):
                    continue
                name = f"{topic.name} {path}"
                d = np.diff(x)
                wrap = bool(np.all(np.abs(x) <= math.pi + 1e-6)
                            and np.any(np.abs(d) > math.pi))
                if wrap:
                    d = _wrapped(d)
                period = float(np.median(np.diff(t))) if t.size > 1 else math.inf
                if not period > 0:
                    # arrivals in bursts (most share a receive time: a loaded machine, a
                    # replayed log): the mean period, never zero (it divides)
                    span = float(np.ptp(t)) if t.size > 1 else 0.0
                    period = span / (t.size - 1) if span > 0 else math.inf
                noise = _robust(d) / math.sqrt(2)
                if noise == 0.0:
                    noise = float(np.std(d)) / math.sqrt(2)
                sig = Signal(SignalRef(topic.name, path), name, t, x, period, noise, wrap,
                             _trend(t, x, noise), frec.info.integer,
                             monotonic=kind == "monotonic", stamp=topic.stamp_path)
                out.append(sig)
    return out


def _trend(t: np.ndarray, x: np.ndarray, noise: float) -> float | None:
    """The slope when a line over time explains at least half the variance and moves the
    signal by more than ten noise std over the run (a discharging battery)."""
    if t.size < 3 or np.ptp(t) <= 0:
        return None
    slope, intercept = np.polyfit(t - t[0], x, 1)
    fitted = intercept + slope * (t - t[0])
    var = float(np.var(x))
    if var <= 0:
        return None
    r2 = 1.0 - float(np.var(x - fitted)) / var
    if r2 >= 0.5 and abs(slope) * float(np.ptp(t)) > 10 * max(noise, 1e-12):
        return float(slope)
    return None


def increasing(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples later than every sample before them (what ``GridCell.add`` keeps)."""
    if t.size == 0:
        return t, x
    before = np.concatenate(([-np.inf], np.maximum.accumulate(t)[:-1]))
    keep = t > before
    return t[keep], x[keep]


def window_means(t: np.ndarray, x: np.ndarray, taus: np.ndarray, step: float,
                 fresh: float) -> np.ndarray:
    """At each ``tau``, the mean over ``[tau - step/2, tau + step/2]`` of the straight lines
    joining the samples ``(t, x)`` (strictly increasing times); NaN where a line spans more
    than ``fresh`` seconds or the samples do not reach. The same arithmetic as
    :class:`blackbox.observe.signals.GridCell`, vectorised."""
    if t.size < 2:
        return np.full(taus.size, np.nan)
    dt = np.diff(t)
    c = np.concatenate(([0.0], np.cumsum(dt * (x[1:] + x[:-1]) * 0.5)))

    def integral(u: np.ndarray) -> np.ndarray:
        i = np.searchsorted(t, u, side="right") - 1
        ok = (i >= 0) & (i < t.size - 1)
        j = np.clip(i, 0, t.size - 2)
        span = dt[j]
        ok &= span <= fresh
        ta, xa, ca = t[j], x[j], c[j]
        with np.errstate(invalid="ignore", divide="ignore"):
            xu = xa + (u - ta) / span * (x[j + 1] - xa)
        out = ca + (u - ta) * (xa + xu) * 0.5
        got: np.ndarray = np.where(ok, out, np.nan)
        return got

    half = step / 2.0
    means: np.ndarray = (integral(taus + half) - integral(taus - half)) / step
    return means


DRIFT_BLOCK = 20
"""Grid steps per block when looking for a drift (one second)."""
DRIFT_T = 3.0
"""A drift's slope must be this many (autocorrelation-inflated) standard errors from 0."""


def drift_of(sig: Signal, peers: Sequence[Signal]) -> float | None:
    """The slope per second of ``sig`` over time beside ``peers`` (regressed together on
    one-second block means), when significant and large enough to leave the signal's
    learned range (0.5 % .. 99.5 %) within an hour; else ``None``."""
    y = _blocks_of(sig.grid, DRIFT_BLOCK)
    cols = [_blocks_of(p.grid, DRIFT_BLOCK) for p in peers]
    t = np.arange(y.size, dtype=np.float64) * STEP * DRIFT_BLOCK
    a = np.stack([np.ones(y.size), t, *cols], axis=1)
    ok = np.isfinite(y) & np.isfinite(a).all(axis=1)
    if ok.sum() < 30:
        return None
    a, y, t = a[ok], y[ok], t[ok]
    sd = a.std(axis=0)
    sd[0] = 1.0
    sd[sd == 0] = 1.0
    coef, *_ = np.linalg.lstsq(a / sd, y, rcond=None)
    coef = coef / sd
    res = y - a @ coef
    if res.size < 3 or float(np.var(res)) == 0.0:
        return None
    rho = float(np.corrcoef(res[:-1], res[1:])[0, 1]) if np.std(res[:-1]) > 0 else 0.0
    rho = min(max(rho, 0.0), 0.95)
    inflate = math.sqrt((1 + rho) / (1 - rho))
    xtx = np.linalg.pinv((a / sd).T @ (a / sd))
    se = math.sqrt(float(np.var(res)) * float(xtx[1, 1])) / sd[1] * inflate
    slope = float(coef[1])
    values = sig.values
    width = float(np.quantile(values, 0.995) - np.quantile(values, 0.005))
    if se > 0 and abs(slope) / se >= DRIFT_T and abs(slope) * 3600.0 > width:
        return slope
    return None


def _blocks_of(x: np.ndarray, block: int) -> np.ndarray:
    n = x.size // block
    if n == 0:
        return np.empty(0)
    b = x[:n * block].reshape(n, block)
    with np.errstate(invalid="ignore"):
        out: np.ndarray = b.mean(axis=1)
    return out


def grid_of(sig: Signal, g0: float, count: int) -> np.ndarray:
    """The signal on the grid ``g0 + k * STEP`` (``window_means``)."""
    t, x = increasing(sig.times, sig.values)
    return window_means(t, x, g0 + np.arange(count) * STEP, STEP, freshness(sig))


ARRIVAL_QUANTILE = 0.999
"""The share of healthy inter-arrival times a relation's judging delay waits out."""


def longest_period(sig: Signal) -> float:
    """The signal's longest healthy inter-arrival time (the ``ARRIVAL_QUANTILE`` quantile,
    so one hiccup does not set it; at least its median period)."""
    t, _ = increasing(sig.times, sig.values)
    if t.size < 2:
        return sig.period
    return max(float(np.quantile(np.diff(t), ARRIVAL_QUANTILE)), sig.period)


def delay_of(signals: Sequence[Signal]) -> float:
    """How late a relation judges a grid point: the sample after its cell must have arrived,
    which takes at most the longest healthy inter-arrival time of its slowest signal after
    the cell (plus a grid step, whole grid steps). Two median periods were waited before:
    a second more than needed for a 1 Hz signal, and every verdict of such a relation came
    that much later, its alarm outlasting the fault by seconds (a GPS relation to a 1 Hz
    odometer still failed 3 s after a GPS fault had ended, naming the odometer; issue 22).
    A sample later than that loses its grid points (the relation is unjudged there), never
    a wrong verdict."""
    waits = [longest_period(s) for s in signals if math.isfinite(s.period)]
    return math.ceil((STEP / 2 + max(waits, default=STEP) + STEP) / STEP - 1e-9) * STEP


def freshness(sig: Signal) -> float:
    return max(3.0 * sig.period, 2 * STEP) if math.isfinite(sig.period) else 2 * STEP


# ---- fitting ------------------------------------------------------------------------------------

def _shifted(x: np.ndarray, lag: int) -> np.ndarray:
    """``x[k - lag]`` at every k (NaN where it does not exist)."""
    out = np.full_like(x, np.nan)
    if lag >= 0:
        out[lag:] = x[:x.size - lag] if lag else x
    else:
        out[:lag] = x[-lag:]
    return out


def best_lag(y: np.ndarray, x: np.ndarray, max_steps: int) -> tuple[int, float]:
    """The lag L maximising ``|corr(y[k], x[k - L])|`` and that correlation."""
    ys = (y - np.nanmean(y)) / (np.nanstd(y) or 1.0)
    xs = (x - np.nanmean(x)) / (np.nanstd(x) or 1.0)
    best, best_c = 0, 0.0
    n = y.size
    for lag in range(-max_steps, max_steps + 1):
        if lag >= 0:
            a, b = ys[lag:], xs[:n - lag]
        else:
            a, b = ys[:lag], xs[-lag:]
        prod = a * b
        ok = np.isfinite(prod)
        if ok.sum() < 50:
            continue
        c = float(prod[ok].mean())
        if abs(c) > abs(best_c):
            best, best_c = lag, c
    return best, best_c


@dataclass
class Fit:
    gains: np.ndarray
    intercept: float
    r2: float
    residual: np.ndarray
    """Out-of-fold residual per grid step (NaN where not computable)."""
    predicted: np.ndarray
    target_steps: int
    lags: list[list[int]]
    slope: float = 0.0
    """The time regressor's gain (a ``trend`` fit): how fast the bias moved, per second."""
    on_changes: tuple[str, ...] = ()
    """Labels of the inputs related on their changes (taps summing to zero)."""


def _ridge(a: np.ndarray, y: np.ndarray, lam: float) -> tuple[np.ndarray, float]:
    mu, sd = a.mean(axis=0), a.std(axis=0)
    sd[sd == 0] = 1.0
    z = (a - mu) / sd
    ym = y.mean()
    gram = z.T @ z + lam * a.shape[0] * np.eye(a.shape[1])
    w = np.linalg.solve(gram, z.T @ (y - ym))
    gains = w / sd
    return gains, float(ym - mu @ gains)


def _r2(y: np.ndarray, p: np.ndarray) -> float:
    var = float(np.var(y))
    return 1.0 - float(np.mean((y - p) ** 2)) / var if var > 0 else -math.inf


def fit(target: np.ndarray, inputs: Sequence[np.ndarray], lags: Sequence[Sequence[int]],
        trend: bool = False, on_changes: Sequence[bool] = ()) -> Fit | None:
    """``target[k - s]`` from ``inputs[i][k - s - lag]`` for each lag, ridge chosen by the
    forward held-out R²; ``s`` makes every lag >= 0 (a target leading its input).
    ``trend``: time is one more regressor (signals that move on their own: the gains are
    not bent by a discharge that happens to follow the load), left out of ``gains`` (the
    observer follows that bias instead). ``on_changes[i]``: the taps of input ``i`` sum to
    zero, so the fit uses its changes (a rate), never its level (:func:`_climbing_choice`)."""
    low = min(min(ls) for ls in lags)
    shift = max(0, -low)
    y = _shifted(target, shift)
    differenced = [bool(on_changes[i]) if i < len(on_changes) else False
                   for i in range(len(inputs))]
    cols: list[np.ndarray] = []
    for x, ls, diff in zip(inputs, lags, differenced, strict=True):
        taps = [_shifted(x, lag + shift) for lag in ls]
        # taps summing to zero: x(t - l_j) - x(t - l_last) for all but the last tap
        cols += [tap - taps[-1] for tap in taps[:-1]] if diff and len(taps) > 1 else taps
    if trend:
        cols.append(np.arange(target.size, dtype=np.float64) * STEP)
    a_all = np.stack(cols, axis=1)
    rows = np.isfinite(y) & np.isfinite(a_all).all(axis=1)
    index = np.flatnonzero(rows)
    if index.size < MIN_GRID_BLOCKS * BLOCK:
        return None
    a, yv = a_all[rows], y[rows]
    cut = int(0.7 * index.size)
    best_lam, best_r2 = 0.0, -math.inf
    for lam in LAMBDAS:
        g, c = _ridge(a[:cut], yv[:cut], lam)
        r2 = _r2(yv[cut:], a[cut:] @ g + c)
        if r2 > best_r2 + 1e-4:
            best_lam, best_r2 = lam, r2
    residual = np.full(target.size, np.nan)
    predicted = np.full(target.size, np.nan)
    folds = np.array_split(np.arange(index.size), 5)
    for fold in folds:
        train = np.ones(index.size, dtype=bool)
        train[fold] = False
        g, c = _ridge(a[train], yv[train], best_lam)
        p = a[fold] @ g + c
        residual[index[fold]] = yv[fold] - p
        predicted[index[fold]] = p
    # the R² reported and judged is of the out-of-fold predictions over the whole run: the
    # last 30 % alone may be one operating mode (driving straight: no yaw to explain)
    oof = residual[index]
    var = float(np.var(yv))
    best_r2 = 1.0 - float(np.mean(oof ** 2)) / var if var > 0 else -math.inf
    gains, intercept = _ridge(a, yv, best_lam)
    slope = 0.0
    if trend:
        gains, slope = gains[:-1], float(gains[-1])
    gains = _tap_gains(gains, [len(ls) for ls in lags], differenced)
    shifted_lags = [[lag + shift for lag in ls] for ls in lags]
    return Fit(gains, intercept, best_r2, residual, predicted, shift, shifted_lags, slope)


def _tap_gains(gains: np.ndarray, taps: Sequence[int],
               differenced: Sequence[bool]) -> np.ndarray:
    """Gains per tap from the fitted ones: an input fitted on its changes has one gain fewer
    (its last tap's is minus the sum of the others)."""
    out: list[float] = []
    i = 0
    for n, diff in zip(taps, differenced, strict=True):
        if diff and n > 1:
            part = [float(g) for g in gains[i:i + n - 1]]
            out += [*part, -sum(part)]
            i += n - 1
        else:
            out += [float(g) for g in gains[i:i + n]]
            i += n
    return np.asarray(out, dtype=np.float64)


def _wide_taps(lags: Sequence[int], period: float) -> list[int]:
    """``lags`` spread so that consecutive taps are at least half of ``period`` apart."""
    center = lags[len(lags) // 2]
    spacing = max(1, round(period / STEP / 2)) if math.isfinite(period) else 1
    half = TAPS // 2
    return [center + spacing * j for j in range(-half, TAPS - half)]


def _taps(center: int) -> list[int]:
    half = TAPS // 2
    return [center + j for j in range(-half, TAPS - half)]


def _blocks(x: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """Block means over ``block`` grid steps, NaN for blocks less than half valid."""
    n = x.size // block
    b = x[:n * block].reshape(n, block)
    valid = np.isfinite(b).sum(axis=1)
    with np.errstate(invalid="ignore"):
        means: np.ndarray = np.nansum(b, axis=1) / np.maximum(valid, 1)
    means[valid * 2 < block] = np.nan
    return means


def block_for(signals: Sequence[Signal]) -> int:
    """Grid steps per residual block of a relation of ``signals``: ``BLOCK``, or as long as
    the slowest signal's period (a 1 Hz battery current: one-second blocks), so each block
    holds about one new sample of every signal. Shorter blocks of a slow signal would be
    averages of the same few samples (the lines joining them), strongly dependent from
    block to block, and their noise would understate how far a block mean wanders."""
    slowest = max((s.period for s in signals if math.isfinite(s.period)), default=STEP)
    return max(BLOCK, round(slowest / STEP))


def widening(samples: int) -> float:
    """The factor on a block noise estimated from a relation whose slowest signal gave
    ``samples`` samples while learning: 1 from ``FEW_SAMPLES`` on, else the upper end of a
    one-sided 99 % interval of a standard deviation estimated from ``samples`` independent
    values (relative standard error ``1 / sqrt(2 (n - 1))``), so a two-minute estimate of a
    1 Hz signal's noise that happened to be low does not become a false alarm an hour."""
    if samples >= FEW_SAMPLES:
        return 1.0
    return 1.0 + WIDEN_Z / math.sqrt(2.0 * max(1, samples - 1))


def _rolling_std(x: np.ndarray, w: int) -> np.ndarray:
    out = np.full(x.size, np.nan)
    if x.size < w:
        return out
    view = np.lib.stride_tricks.sliding_window_view(x, w)
    out[w - 1:] = view.std(axis=1)
    return out


def tracked(z: np.ndarray, alpha: float, limit: float = math.inf) -> np.ndarray:
    """``z`` less a bias followed by exponential smoothing (weight ``alpha`` per block),
    moving by at most ``limit`` per block: what the relation observer does with ``track``
    and ``track_rate``."""
    out = np.empty_like(z)
    bias = 0.0
    for i, x in enumerate(z.tolist()):
        d = x - bias
        out[i] = d
        bias += min(limit, max(-limit, alpha * d))
    return out


def change(x: np.ndarray, steps: int = CHANGE_STEPS) -> np.ndarray:
    """``x[k] - x[k - steps]`` (NaN for the first ``steps``)."""
    out = np.full_like(x, np.nan)
    out[steps:] = x[steps:] - x[:-steps]
    return out


RATE_STEPS = 10
"""Grid steps a climbing signal's rate is screened over (half a second)."""


def rate(x: np.ndarray) -> np.ndarray:
    """``x[k] - x[k - RATE_STEPS]``: a climbing signal's speed, for screening."""
    return change(x, RATE_STEPS)


def change_r2(fitted: Fit, target: np.ndarray) -> float:
    """How much of the target's one-second changes the fit explains (out of fold): for
    trending signals, whose levels any two climbing signals would "explain"."""
    dy = change(target)
    dr = change(fitted.residual)
    ok = np.isfinite(dy) & np.isfinite(dr)
    if ok.sum() < MIN_GRID_BLOCKS * BLOCK // 2:
        return -math.inf
    var = float(np.var(dy[ok]))
    return 1.0 - float(np.mean(dr[ok] ** 2)) / var if var > 0 else -math.inf


def relation_from_fit(target: Signal, inputs: list[Signal], fitted: Fit) -> Relation | None:
    """Residual noise per mode, sensitivity and span of a fitted relation; ``None`` when it
    cannot see a fault of four noise std on one of its signals. Blocks are ``block_for``
    its signals; learned from few samples of its slowest signal, the noise of each mode is
    widened (:func:`widening`)."""
    block = block_for([target, *inputs])
    widen = widening(min(s.values.size for s in (target, *inputs)))
    res_b = _blocks(fitted.residual, block)
    pred_b = _blocks(fitted.predicted, block)
    ok = np.isfinite(res_b) & np.isfinite(pred_b)
    if ok.sum() < MIN_GRID_BLOCKS * BLOCK / block:
        return None
    noise_all = float(np.std(res_b[ok])) or 1e-12
    window = max(2, round(WINDOW / (STEP * block)))
    spread = _rolling_std(np.where(ok, pred_b, np.nan), window)
    excitation = EXCITATION * noise_all
    moving = ok & (spread >= excitation)
    still = ok & np.isfinite(spread) & (spread < excitation)
    if moving.sum() < MIN_GRID_BLOCKS * BLOCK / block / 2:
        if still.sum() < MIN_GRID_BLOCKS * BLOCK / block:
            return None
        # the prediction never moves much beside the residual's noise (a battery voltage
        # sagging a little under its current): one mode, judged always
        excitation = 0.0
        moving, still = ok, np.zeros_like(ok)
    trending = any(s.trend is not None or s.drift is not None for s in (target, *inputs))
    track = TRACK if trending else None
    track_rate = None
    if trending:
        # the bias moves, at a bounded rate (five times what it did while learning, as the
        # load may be heavier later, and at least a twentieth of the block noise a second):
        # a fault's offset or drift, far faster, is not followed
        track_rate = max(TRACK_RATE * abs(fitted.slope), 0.05 * noise_all)
        limit = track_rate * STEP * block / noise_all
        res_b = res_b.copy()
        res_b[ok] = tracked(res_b[ok] / noise_all, STEP * block / TRACK, limit) * noise_all
    m_bias = float(res_b[moving].mean())
    m_noise = (float(res_b[moving].std()) or noise_all) * widen
    z_parts = [(res_b[moving] - m_bias) / m_noise]
    still_mode = None
    if still.sum() >= MIN_STILL_BLOCKS * BLOCK / block:
        s_bias = float(res_b[still].mean())
        s_noise = (float(res_b[still].std()) or noise_all) * widen
        still_mode = (s_bias, s_noise)
        z_parts.append((res_b[still] - s_bias) / s_noise)
    z_all = np.concatenate(z_parts)
    n_in = len(inputs)
    per = len(fitted.gains) // n_in
    gains = [fitted.gains[i * per:(i + 1) * per].tolist() for i in range(n_in)]
    noise_mode = max(m_noise, still_mode[1] if still_mode else 0.0)
    seen_target = 4 * target.noise / noise_mode
    seen = [4 * sig.noise * abs(sum(g)) / noise_mode for sig, g in zip(inputs, gains,
                                                                      strict=True)]
    if seen_target < SENSITIVITY:
        return None
    # one that sees its target but not a fault of its inputs (a clean command beside a
    # noisy sensor) still accuses when it fails; held, it clears nobody
    clears = min(seen) >= SENSITIVITY
    sensitivity = min(seen_target, *seen)
    p = fitted.predicted[np.isfinite(fitted.predicted)]
    lo, hi = float(p.min()), float(p.max())
    margin = 0.25 * (hi - lo) + 3 * noise_all
    residual = fitted.residual[np.isfinite(fitted.residual)]
    return Relation(target, [(s, lags) for s, lags in zip(inputs, fitted.lags, strict=True)],
                    gains, fitted.intercept, fitted.target_steps, fitted.r2,
                    float(np.std(residual)), (m_bias, m_noise), still_mode, excitation,
                    (lo - margin, hi + margin), z_all, sensitivity, track=track,
                    track_rate=track_rate, clears=clears, on_changes=fitted.on_changes,
                    block=block, widen=widen)


def clear_only_what_they_see(relations: Sequence[Relation]) -> None:
    """Turn ``clears`` off where a fault of four noise std on an input would not break the
    relation, with each signal's noise bounded by the residual of the relations predicting
    it as well as by its consecutive differences.

    The differences overstate the noise of a signal sampled slowly beside the motion it
    follows (a 2 Hz battery current: three times its noise), and with it how far a fault
    of that signal moves the relations it feeds. A voltage ~ current relation then claimed
    to see current offsets it cannot (a 0.08 ohm sag hides an offset of 0.2 A in the
    voltage's noise) and, held, cleared the current while the current ~ speed relation
    failed: no diagnosis at all. A relation's out-of-fold residual contains its target's
    noise, so the smallest such residual bounds that noise too.
    """
    bound: dict[SignalRef, float] = {}
    for r in relations:
        key = r.target.ref
        bound[key] = min(bound.get(key, math.inf), r.noise)
    for r in relations:
        if not r.clears:
            continue
        noise_mode = max(r.moving[1], r.still[1] if r.still is not None else 0.0)
        seen = [4 * min(sig.noise, bound.get(sig.ref, math.inf)) * abs(sum(g)) / noise_mode
                for (sig, _), g in zip(r.inputs, r.gains, strict=True)]
        if min(seen) < SENSITIVITY:
            r.clears = False


def relation_drift(sensitivity: float) -> float:
    """The CUSUM drift ``k`` of a relation: half the smallest shift it must see (a fault of
    four noise std on any of its signals moves its residual by ``sensitivity`` block noise),
    between ``K`` and ``K_MAX``. A real robot's residual wanders with its operating mode
    (bias moves of 0.3-0.5 block noise for tens of seconds on the real diffdrive robots);
    a CUSUM tuned for a shift of one block noise sums that wander up (simulated, a 0.5
    wander held for 60 blocks: 29 false alarms an hour at k 0.5, 3 at k 1.25), one tuned
    for the faults it must see does not, and finds those sooner (a 3-block-noise shift in
    4 blocks instead of 6.5)."""
    return min(K_MAX, max(K, sensitivity / 2))


def learn_relations(rec: Recording) -> RelationsLearned:
    notes: list[str] = []
    signals = signals_of(rec, notes)
    trends: dict[str, list[str]] = {}
    for s in signals:
        if s.trend is not None:
            trends.setdefault(s.ref.topic, []).append(
                f"{s.ref.field} trend: {s.trend:+.4g} per s over the run (noise std "
                f"{s.noise:.3g}): no band, it would leave it; checked for being alive")
    liveness: dict[str, list[Liveness]] = {}
    for s in signals:
        live = learn_liveness(s)
        if live is not None:
            liveness.setdefault(s.ref.topic, []).append(live)
    related = [s for s in signals if not s.wrap]
    few = [s for s in related if s.values.size < MIN_RELATION_SAMPLES]
    if few:
        notes.append(f"{', '.join(s.ref.label() for s in few)}: fewer than "
                     f"{MIN_RELATION_SAMPLES} samples while learning, not related (too few to "
                     "fit a relation and calibrate its threshold); checked for being alive")
        related = [s for s in related if s.values.size >= MIN_RELATION_SAMPLES]
    relations: list[Relation] = []
    if rec.duration > 0:
        g0 = math.ceil(rec.started / STEP) * STEP
        count = int((rec.ended - g0) / STEP) + 1
        for s in signals:
            s.grid = grid_of(s, g0, count)
        for s in signals:
            if s.trend is None:
                s.drift = drift_of(s, [p for p in signals if p.ref.topic == s.ref.topic
                                       and p is not s and p.trend is None])
                if s.drift is not None:
                    trends.setdefault(s.ref.topic, []).append(
                        f"{s.ref.field} trend: drifts {s.drift * 3600:+.4g} per hour beside "
                        "the other signals of its topic (more than its learned range): no "
                        "band, it would leave it; checked for being alive")
    if rec.duration > 0 and len(related) >= 2:
        relations = _search(related, notes)
        clear_only_what_they_see(relations)
    checks = len(relations) + sum(1 for ls in liveness.values() for live in ls
                                  if live.z is not None)
    rate = FALSE_ALARMS_PER_HOUR / max(1, checks)
    for i, r in enumerate(relations):
        r.calibration = calibrate(r.z, 3600.0 / (STEP * r.block), rate,
                                  k=relation_drift(r.sensitivity), seed=i)
    for ls in liveness.values():
        for j, live in enumerate(ls):
            if live.z is not None:
                per_hour = 3600.0 / (live.signal.period * live.block)
                live.calibration = calibrate(live.z, per_hour, rate, two_sided=False,
                                             k=noise_drift(live.std), seed=1000 + j)
    if not relations and len(related) >= 2:
        notes.append(f"no relation between signals of different topics reached a held-out "
                     f"R2 of {R2_MIN:g} in {rec.duration:.0f} s")
    related_fields: dict[str, set[str]] = {}
    for r in relations:
        for s in (r.target, *(i for i, _ in r.inputs)):
            related_fields.setdefault(s.ref.topic, set()).add(s.ref.field)
    return RelationsLearned(relations, liveness, trends, notes, len(signals), related_fields)


LEVEL_IDENTITY = 0.98
"""The R² (of the target's changes) above which a trending input's level may be the
relation: two encoders of one wheel side, two odometers."""


def _climbing_choice(rates_r2: float, level_r2: float) -> str | None:
    """How to relate inputs that climb: ``"changes"`` (taps summing to zero) whenever their
    changes explain the target, else ``"level"`` only for a near-identity (two encoders of
    one wheel: their changes say nothing of the level), else ``None``: not related.

    Two signals that climb or wander over a run correlate in level whatever their relation
    (a spurious regression): on sim:skidsteer the battery voltage was fitted on the four
    wheel angles, whose left-right difference is the heading, a random walk; the level fit
    explained more of the two minutes (R² 0.89 against 0.72 on changes) because it could
    use that chance, and hours later its prediction had wandered off with the heading. Even
    a fit that is a rate in all but name keeps a small level term (a motor current against
    a wheel angle: taps 30.7, -1.5, -29.2), which an hour of driving multiplies."""
    if rates_r2 >= R2_MIN:
        return "changes"
    if level_r2 >= LEVEL_IDENTITY:
        return "level"
    return None


JOINT_SHARE = 0.5
"""A joint relation replaces the best single input's when its held-out unexplained variance
is at most this share of the single one's (:func:`prefer_joint`)."""


def prefer_joint(single_r2: float, joint_r2: float) -> bool:
    """Whether a relation from several signals of one topic explains materially more than
    the one from its best single signal: its held-out (five contiguous folds, so time-
    blocked) unexplained variance ``1 - R2`` is at most ``JOINT_SHARE`` of the single one's.
    Both pass ``R2_MIN``; what one signal leaves unexplained is not noise when a peer
    explains half of it (a wheel speed from the forward command alone leaves the yaw rate's
    share, which wanders with every turn and reads as a bias for seconds), and a peer that
    explains less is chance or noise, not worth more inputs that faults can move."""
    return (1.0 - joint_r2) <= JOINT_SHARE * (1.0 - single_r2)


def _trending(s: Signal) -> bool:
    return s.trend is not None or s.drift is not None


def _search(signals: list[Signal], notes: list[str]) -> list[Relation]:
    """Per target, the best relation from each other topic; a signal with none from another
    topic (a battery voltage, a climbing wheel angle) may be related within its own topic.
    Trending signals are screened and judged on their five-second changes."""
    max_steps = round(MAX_LAG / STEP)
    changes = {i: change(s.grid) for i, s in enumerate(signals) if _trending(s)}
    corr: dict[tuple[int, int], tuple[int, float]] = {}
    for i, a in enumerate(signals):
        for j in range(i + 1, len(signals)):
            b = signals[j]
            if i in changes or j in changes:
                ga = changes.get(i, change(a.grid)) if j in changes else a.grid
                gb = changes.get(j, change(b.grid)) if i in changes else b.grid
                corr[(i, j)] = best_lag(ga, gb, max_steps)
                climbing = [k for k in (i, j) if signals[k].trend is not None]
                if len(climbing) == 1 and not _trending(signals[i + j - climbing[0]]):
                    # a level beside a climbing signal's rate (a current beside a wheel
                    # angle's speed); the lag is the rate's: RATE_STEPS // 2 later
                    up = climbing[0]
                    lag, c_rate = best_lag(signals[i + j - up].grid, rate(signals[up].grid),
                                           max_steps)
                    lag += RATE_STEPS // 2
                    if abs(c_rate) > abs(corr[(i, j)][1]):
                        corr[(i, j)] = (lag if up == j else -lag, c_rate)
            else:
                corr[(i, j)] = best_lag(a.grid, b.grid, max_steps)

    def lag_corr(t: int, x: int) -> tuple[int, float]:
        """Lag of x relative to target t, and the correlation."""
        if t < x:
            return corr[(t, x)]
        lag, c = corr[(x, t)]
        return -lag, c

    def quality(target: Signal, inputs: list[Signal], fitted: Fit) -> float:
        if _trending(target) or any(_trending(x) for x in inputs):
            return change_r2(fitted, target.grid)
        return fitted.r2

    def fitted_for(target: Signal, inputs: list[Signal], lags: list[list[int]]) -> Fit | None:
        """The fit of ``target`` from ``inputs``, its ``r2`` the quality it is judged by;
        climbing inputs are related on their changes unless only their level, as an
        identity, explains the target (:func:`_climbing_choice`); a relation that holds
        only on the levels of climbing inputs is left out, with the reason in the learned
        file's notes."""
        trend = _trending(target) or any(_trending(x) for x in inputs)
        grids = [x.grid for x in inputs]
        level = fit(target.grid, grids, lags, trend)
        if level is not None:
            level.r2 = quality(target, inputs, level)
        # inputs that climb over the run (a line explains most of them: wheel angles, an
        # odometer); one that only drifts beside its topic's other signals (a current over
        # two minutes of one driving pattern) keeps its level, which may be the relation
        # (a voltage sagging with the current)
        moving = [x.trend is not None for x in inputs]
        if not any(moving):
            return level
        rates = fit(target.grid, grids, lags, trend, moving)
        if rates is not None:
            rates.r2 = quality(target, inputs, rates)
            rates.on_changes = tuple(x.ref.label() for x, m in zip(inputs, moving, strict=True)
                                     if m)
        choice = _climbing_choice(-math.inf if rates is None else rates.r2,
                                  -math.inf if level is None else level.r2)
        if choice == "level" and any(x.monotonic for x in inputs):
            choice = None  # an odometer's level relates to nothing (Signal.monotonic)
        if choice == "changes":
            return rates
        if choice == "level" or level is None or level.r2 < R2_MIN:
            return level
        why = (f"{target.ref.label()} from {', '.join(x.ref.label() for x in inputs)}: not "
               f"related: R2 {level.r2:.3f} on the climbing inputs' levels, "
               f"{-math.inf if rates is None else rates.r2:.3f} on their changes (a level "
               "that climbs or wanders relates anything that climbs with it; only an "
               f"identity, R2 >= {LEVEL_IDENTITY:g}, is related on levels)")
        if why not in notes:
            notes.append(why)
        return rates

    def single_or_joint(target: Signal, single: tuple[Signal, int] | None,
                        joint: list[tuple[Signal, int]], common: Sequence[int],
                        r2_min: float) -> Relation | None:
        """The relation of ``target`` from its ``single`` best peer (at its lag), or from
        the ``joint`` peers when together they explain materially more
        (:func:`prefer_joint`): each joint input at its own best lag, or all at one of
        ``common``; either kept at a held-out R2 of ``r2_min``."""
        alone: Relation | None = None
        if single is not None:
            fitted = fitted_for(target, [single[0]], [_taps(single[1])])
            if fitted is not None and fitted.r2 >= r2_min:
                alone = relation_from_fit(target, [single[0]], fitted)
        if len(joint) >= 2:
            inputs = [x for x, _ in joint]
            best: Fit | None = None
            for lags in [[_taps(lag) for _, lag in joint], *([_taps(c)] * len(joint)
                                                            for c in common)]:
                fitted = fitted_for(target, inputs, lags)
                if fitted is not None and (best is None or fitted.r2 > best.r2 + 1e-4):
                    best = fitted
            if best is not None and best.r2 >= r2_min and (
                    alone is None or prefer_joint(alone.r2, best.r2)):
                together = relation_from_fit(target, inputs, best)
                if together is not None:
                    return together
        return alone

    def from_topic(ti: int, topic: str) -> Relation | None:
        target = signals[ti]
        if target.monotonic:
            return None
        peers = [(xi, *lag_corr(ti, xi)) for xi, s in enumerate(signals)
                 if s.ref.topic == topic and xi != ti]
        peers.sort(key=lambda p: -abs(p[2]))
        single = ((signals[peers[0][0]], peers[0][1])
                  if peers and abs(peers[0][2]) >= SCREEN else None)
        # together, signals may explain what none does alone (a yaw rate from the left and
        # right wheel speeds, each mostly the forward speed): the best few of the same kind
        # (trending or not) as the target, whatever their single correlation; or explain
        # materially more than the best one alone (a wheel speed turns with the forward
        # speed and the yaw rate: from the forward command alone its residual wanders with
        # every turn), which the held-out residuals decide (:func:`prefer_joint`)
        joint = [(signals[xi], lag) for xi, lag, _ in peers
                 if _trending(signals[xi]) == _trending(target)][:MAX_JOINT]
        # each input at its own best lag, or all at one: a signal that is mostly another
        # quantity (a wheel speed is mostly the forward speed) correlates best with the
        # target at a lag that says nothing of the delay (a yaw rate from four wheel
        # speeds: R2 0.77 at their own lags, 0.995 all at 0)
        common = [] if _trending(target) else sorted({0, *(lag for _, lag in joint)})
        return single_or_joint(target, single, joint, common, R2_MIN)

    def by_magnitude(ti: int, topic: str) -> Relation | None:
        """A signal no other topic relates linearly, from the absolute values of a topic's
        signals (a current that grows with the forward and the turning speed, whichever
        their sign): the single best, or together when that explains materially more."""
        target = signals[ti]
        if target.monotonic:
            return None
        mags = magnitudes_of([s for s in signals if s.ref.topic == topic])
        peers = sorted(((m, *best_lag(target.grid, m.grid, max_steps)) for m in mags),
                       key=lambda p: -abs(p[2]))
        if not peers or abs(peers[0][2]) < SCREEN:
            return None
        joint = [(m, lag) for m, lag, _ in peers[:MAX_JOINT]]
        return single_or_joint(target, joint[0], joint, [0], MAGNITUDE_R2_MIN)

    by_target: dict[int, list[Relation]] = {}
    topics = sorted({s.ref.topic for s in signals})
    for ti, target in enumerate(signals):
        found = [r for topic in topics if topic != target.ref.topic
                 for r in [from_topic(ti, topic)] if r is not None]
        if not found:
            found = [r for topic in topics if topic != target.ref.topic
                     for r in [by_magnitude(ti, topic)] if r is not None]
        if not found:
            own = from_topic(ti, target.ref.topic)
            found = [own] if own is not None else []
        found.sort(key=lambda r: -r.r2)
        by_target[ti] = found[:MAX_PEERS]
    # one direction per pair of single signals: the cleaner signal is the input
    kept: list[Relation] = []
    seen: set[frozenset[str]] = set()
    every = sorted((r for rs in by_target.values() for r in rs),
                   key=lambda r: (len(r.inputs), _relative_noise(r.inputs[0][0])
                                  - _relative_noise(r.target)))
    for r in every:
        key = frozenset({r.target.name, *(s.name for s, _ in r.inputs)})
        if len(r.inputs) == 1 and key in seen:
            continue
        seen.add(key)
        kept.append(r)
    return sorted(kept, key=lambda r: (r.topics, r.target.name))


MAGNITUDE_R2_MIN = 0.95
"""The held-out R² a relation from absolute values must reach: a magnitude fits much that
is not the relation (one wheel's speed stands for the robot's speed and turn while the
two minutes of learning drive one way), so only a near-exact one is kept."""


def magnitudes_of(signals: Sequence[Signal]) -> list[Signal]:
    """The absolute values of the signals that take both signs around zero (a speed, a yaw
    rate), as inputs: not those that trend, count or wrap, nor those of one sign, whose
    magnitude is the signal itself."""
    out = []
    for s in signals:
        if _trending(s) or s.monotonic or s.wrap or s.grid.size == 0:
            continue
        g = s.grid[np.isfinite(s.grid)]
        if g.size == 0:
            continue
        spread = float(np.percentile(g, 95) - np.percentile(g, 5))
        if spread <= 0 or min(-float(np.percentile(g, 5)), float(np.percentile(g, 95))) \
                < 0.1 * spread:
            continue
        out.append(replace(s, grid=np.abs(s.grid), magnitude=True))
    return out


def _relative_noise(s: Signal) -> float:
    var = float(np.nanvar(s.grid)) if s.grid.size else 0.0
    return s.noise ** 2 / var if var > 0 else math.inf


# ---- liveness -----------------------------------------------------------------------------------

def _longest_run(x: np.ndarray) -> int:
    if x.size == 0:
        return 0
    same = np.concatenate(([False], x[1:] == x[:-1]))
    best = run = 1
    for s in same[1:].tolist():
        run = run + 1 if s else 1
        best = max(best, run)
    return best


RATE_MARGIN = 1.5
"""A climbing signal may change this many times as fast as it did while learning."""
SLOW_STUCK_PERIOD = 0.2
"""A signal this slow or slower (5 Hz) is stuck at three equal samples when continuous."""


def stuck_repeats(s: Signal, longest: int) -> int | None:
    """Equal samples in a row that mean stuck, ``None`` for a signal that repeats too
    often to tell. At least five and twice the longest healthy run; but three for a slow
    signal (``SLOW_STUCK_PERIOD``) whose values never repeated and whose changes are all
    distinct: continuous noise repeats a value with a probability of nothing, so three equal
    samples are a frozen sensor, found in about two of its periods instead of four (a 1 Hz
    temperature stuck for 4-5 s before it was reported, sim:skidsteer). A quantised signal
    (its changes fall on a grid and repeat) keeps five: two minutes at 1 Hz cannot show
    that it never repeats three times in an hour."""
    if longest > 3:
        return None
    if longest == 1 and s.period >= SLOW_STUCK_PERIOD and _continuous(s.values):
        return 3
    return max(5, 2 * longest + 1)


def _continuous(x: np.ndarray) -> bool:
    """Whether the changes of ``x`` are all distinct (no grid of values), over enough of
    them to tell."""
    d = np.abs(np.diff(x))
    d = d[d > 0]
    return bool(d.size >= 20 and np.unique(d).size >= 0.95 * d.size)


def fastest_change(s: Signal) -> float:
    """The largest ``|x[k] - x[k-1]| / max(t[k] - t[k-1], period)`` of the healthy samples
    (angles the short way round): the time between samples is at least the median period,
    as arrivals in bursts share a receive time."""
    t, x = increasing(s.times, s.values)
    if t.size < 2:
        return 0.0
    d = np.diff(x)
    if s.wrap:
        d = _wrapped(d)
    return float(np.max(np.abs(d) / np.maximum(np.diff(t), s.period)))


def rate_bound(s: Signal) -> float | None:
    """The most a signal that climbs (``Signal.trend``: a wheel angle, an odometer, a
    warming motor) may change per second between consecutive samples: ``RATE_MARGIN``
    times the fastest seen while learning (item 7 of issue 22: a trend is related or its
    rate is bounded). Such a signal is an integral of something (distance, heat), smooth
    by nature, so a step is a fault: an odometer scaled or offset jumps by thousands of
    counts where it climbed by a hundred a second, a temperature scaled by 0.65 by nine
    degrees; neither is in any relation's reach (an odometer is related on its changes
    only, a warming motor to nothing). A margin of 1.5: the largest of an hour's noise
    steps is about 1.35 times that of two minutes (Gaussian tails, 3600 against 120
    samples), and a robot may drive a little faster later."""
    if s.trend is None or not math.isfinite(s.period) or s.period <= 0:
        return None
    fastest = fastest_change(s)
    return RATE_MARGIN * fastest if fastest > 0 else None


def learn_liveness(s: Signal) -> Liveness | None:
    if not math.isfinite(s.period):
        return None  # every sample at one time: nothing says how often it moves
    rate = rate_bound(s)
    x = s.values
    longest = _longest_run(x)
    repeats = stuck_repeats(s, longest)
    block = max(5, round(LIVENESS_BLOCK_SECONDS / s.period)) if s.period > 0 else 5
    d = np.diff(x)
    if s.wrap:
        d = _wrapped(d)
    d = np.diff(d)  # second differences: smooth motion (a turn starting) is not noise
    if d.size // block < LIVE_BLOCKS:
        block = SLOW_LIVE_BLOCK  # a slow signal (1 Hz for two minutes): shorter blocks
    n = d.size // block
    z: np.ndarray | None = None
    mean = std = 0.0
    squares = d ** 2
    typical = float(squares.mean()) if squares.size else 0.0
    cap = NOISE_CAP * typical if typical > 0 and math.isfinite(typical) else None
    if cap is not None:
        squares = np.minimum(squares, cap)
    if n >= MIN_LIVE_BLOCKS:
        sq = squares[:n * block].reshape(n, block).mean(axis=1)
        # a quantised signal has blocks without a change: they can only lower the upward
        # statistic, so the noise is learned from the others (when most blocks change)
        sq = sq[sq > 0]
        if sq.size >= max(MIN_LIVE_BLOCKS, n // 2):
            v = np.log(sq)
            mean, std = float(v.mean()), max(float(v.std()), 0.05)
            if sq.size < LIVE_BLOCKS:  # few blocks: their spread is widened (widening)
                std *= widening(sq.size)
            z = (v - mean) / std
    if repeats is None and z is None and rate is None:
        return None
    return Liveness(s, repeats, longest, block, mean, std, z, rate=rate,
                    fastest=fastest_change(s) if rate is not None else 0.0,
                    cap=cap if z is not None else None)


# ---- configuration entries ----------------------------------------------------------------------

def _name(text: str) -> str:
    import re

    name = re.sub(r"[^A-Za-z0-9_]+", "_", text).strip("_") or "signal"
    return f"s_{name}" if name[0].isdigit() else name


def _g(x: float, digits: int = 6) -> float:
    return float(f"{x:.{digits}g}")


def _zero_sum(gains: Sequence[float], digits: int = 7) -> list[float]:
    """Gains of an input related on its changes, written so that they still sum to zero:
    rounded to significant digits they would not, and the remainder times a wheel angle an
    hour of driving later is a false alarm (a sum of 3e-5 times 3600 rad: seven noise std
    of a motor current)."""
    top = max((abs(g) for g in gains), default=0.0)
    decimals = digits - 1 - (math.floor(math.log10(top)) if top > 0 else 0)
    head = [round(float(g), decimals) for g in gains[:-1]]
    return [*head, -sum(head)]


def relation_entry(pair: tuple[str, str], relations: Sequence[Relation]) -> dict[str, Any]:
    signals = [s for r in relations for s in (r.target, *(i for i, _ in r.inputs))]
    fresh = max(freshness(s) for s in signals)
    items = []
    names: set[str] = set()
    for r in relations:
        name = _name(f"{r.target.ref.topic}_{r.target.ref.field}")
        while name in names:
            name += "_"
        names.add(name)
        assert r.calibration is not None
        items.append({
            "name": name,
            "target": {"topic": r.target.ref.topic, "field": r.target.ref.field},
            **({"target_lag": _g(r.target_steps * STEP)} if r.target_steps else {}),
            "inputs": [{"topic": s.ref.topic, "field": s.ref.field,
                        **({"magnitude": True} if s.magnitude else {}),
                        "lags": [_g(lag * STEP) for lag in lags],
                        "gains": (_zero_sum(gains) if s.ref.label() in r.on_changes
                                  else [_g(g) for g in gains])}
                       for (s, lags), gains in zip(r.inputs, r.gains, strict=True)],
            "intercept": _g(r.intercept),
            "bias": _g(r.moving[0], 4),
            "block_noise": _g(r.moving[1], 4),
            "still": (None if r.still is None else
                      {"bias": _g(r.still[0], 4), "block_noise": _g(r.still[1], 4)}),
            "cusum": {"k": _g(r.calibration.k, 4), "h": round_up(r.calibration.h, 3)},
            "excitation": _g(r.excitation, 4),
            **({"track": r.track, "track_rate": _g(r.track_rate or 0.0, 4)}
               if r.track is not None else {}),
            **({} if r.clears else {"clears": False}),
            "span": [round_down(r.span[0]), round_up(r.span[1])],
        })
    stamps = {s.ref.topic: s.stamp for s in signals if s.stamp is not None}
    return {"type": "relation", "topic": pair[0], "topic_b": pair[1], "step": STEP,
            "block": _entry_block(relations), "window": WINDOW, "fresh": round_up(fresh, 2),
            "delay": _g(delay_of(signals)),
            **({"stamps": dict(sorted(stamps.items()))} if stamps else {}),
            "relations": items}


def _few(r: Relation) -> str:
    """What the comment says of a relation learned from few samples (nothing otherwise)."""
    if r.widen == 1.0:
        return ""
    slowest = min(s.values.size for s in (r.target, *(i for i, _ in r.inputs)))
    return (f" (blocks of {r.block * STEP:g} s; widened x{r.widen:.2f}: {slowest} samples of "
            "its slowest signal)")


def _entry_block(relations: Sequence[Relation]) -> int:
    """The block of a topic pair's relations: one, as every relation of the pair relates
    signals of both topics (whose periods are their topics')."""
    return max(r.block for r in relations)


def relation_comments(relations: Sequence[Relation]) -> list[str]:
    out = []
    for r in relations:
        assert r.calibration is not None
        inputs = ", ".join(f"{'|' + s.ref.label() + '|' if s.magnitude else s.ref.label()} "
                           f"(lags {lags[0] * STEP:g}..{lags[-1] * STEP:g} s)"
                           for s, lags in r.inputs)
        mode = ("standing still judged with its own noise" if r.still is not None
                else "unjudged while standing still (not seen while learning)")
        if r.track is not None:
            mode += (f"; its signals move on their own: R2 of five-second changes, the bias "
                     f"followed over {r.track:g} s, at most {r.track_rate or 0.0:.3g} a second")
        if r.on_changes:
            mode += (f"; related on the changes of {', '.join(r.on_changes)} (taps summing "
                     "to zero: they trend, and a level that climbs would relate anything that "
                     "climbs with it)")
        seen = (f"a 4-noise-std fault on any of its signals moves the residual >= "
                f"{r.sensitivity:.1f} block noise" if r.clears else
                f"its inputs' faults of 4 noise std move the residual less than {SENSITIVITY:g} "
                "block noise: held, it clears its target alone")
        out.append(f"{r.target.ref.label()} from {inputs}: held-out R2 {r.r2:.4f}, residual "
                   f"std {r.noise:.3g}, block noise {r.moving[1]:.3g}{_few(r)}; {seen}; "
                   f"{r.calibration.describe()}; {mode}")
    return out


def liveness_entry(topic: str, lives: Sequence[Liveness]) -> dict[str, Any]:
    items = []
    names: set[str] = set()
    for live in lives:
        name = _name(live.signal.ref.field)
        while name in names:
            name += "_"
        names.add(name)
        item: dict[str, Any] = {"name": name, "field": live.signal.ref.field}
        if live.repeats is not None:
            item["repeats"] = live.repeats
        if live.z is not None and live.calibration is not None:
            item["noise"] = {"block": live.block, "mean": _g(live.mean, 5),
                             "std": _g(live.std, 4),
                             **({"cap": _g(live.cap, 4)} if live.cap is not None else {}),
                             "cusum": {"k": live.calibration.k,
                                       "h": round_up(live.calibration.h, 3)}}
        if live.rate is not None:
            item["rate"] = {"at_most": round_up(live.rate, 3),
                            "period": _g(live.signal.period, 4)}
        if live.signal.wrap:
            item["wrap"] = True
        items.append(item)
    fresh = max(max(2.0 * freshness(live.signal) for live in lives), 1.0)
    return {"type": "liveness", "topic": topic, "fresh": round_up(fresh, 2), "signals": items}


def liveness_comments(lives: Sequence[Liveness]) -> list[str]:
    out = []
    for live in lives:
        parts = []
        if live.repeats is not None:
            parts.append(f"stuck at {live.repeats} equal samples (longest healthy run "
                         f"{live.longest_run})")
        else:
            parts.append(f"repeats up to {live.longest_run} equal samples while healthy: no "
                         "stuck check")
        if live.calibration is not None:
            capped = (f" (each difference squared at most {live.cap:.3g}, {NOISE_CAP:g} x "
                      "the healthy mean: a step is not a burst)" if live.cap is not None
                      else "")
            parts.append(f"log mean squared difference per {live.block} samples "
                         f"{live.mean:.3g} +- {live.std:.3g}{capped}, "
                         f"{live.calibration.describe()}")
        else:
            parts.append("no noise check (frozen blocks or too few samples while healthy)")
        if live.rate is not None:
            parts.append(f"it climbs: changes at most {live.rate:.4g} a second between "
                         f"samples ({RATE_MARGIN:g} x the fastest while learning, "
                         f"{live.fastest:.4g}; a step is a fault)")
        out.append(f"alive {live.signal.ref.field}: " + "; ".join(parts))
    return out
