"""Sensor fault detection and diagnosis (SFDD): judging one window of correlated signals.

The method of Khalastchi et al. (thesis reference [32]) as the thesis summarises it in
section 4.2, with the variants Biswas proposed (reference [41], same section). The papers'
own texts were not available to this project (searched for, not found), so section and
equation numbers below are the thesis's, and every step cites the thesis's wording:

1. A sliding window ``H`` of ``m`` time steps by ``n`` one-dimensional sensors, low-pass
   filtered first ("this noise needs to be filtered first using some low-pass filters"):
   here a moving average of ``smoothing`` samples.
2. The window is split in two parts ("split into two halves"; ``split`` makes the share
   configurable). On the first part a Pearson correlation test finds, for every sensor, the
   set of sensors correlated with it (``|r| >= correlation``, "a user defined threshold
   between 0 and 1").
3. On the second part the correlations are checked again; a sensor whose correlations do
   not hold is *uncertain* and gets a pattern: ``stuck`` ("produces the same value even after
   its correlated sensors have changed behaviour") or ``drift`` ("deviated over time"),
   found with simple linear regression as the thesis reports the authors advise.
4. A suspicious sensor is cleared when its correlated sensors show the same behaviour (a
   response of the system, not a fault): here a sensor is suspect when some correlated pair
   disagrees and cleared when any correlated signal still agrees with it; a stuck sensor is
   faulty only when most of its peers still move. With only two correlated signals both are
   suspect; the structural model (:mod:`blackbox.diagnose.sfdd_live`) reports both.

Biswas's variants (section 4.2, paragraph on [41]) are options of :class:`SfddSettings`:
``signed`` keeps the sign of a correlation (a pair whose correlation flips sign no longer
holds; [32] as described takes the absolute value), ``references`` correlates every signal
with a few reference signals instead of all pairs (cost ``O(m n k)`` instead of
``O(m n^2)``), and ``change`` flags a change of correlation between the two parts instead of
a loss of correlation.

Beyond the papers (our extension, on by default, off with ``strict=True``): the regression
of each sensor on each correlated peer, fitted on the first part, predicts the second part;
the residual's trend (``drift``), mean shift and spread (``deviation``: offset and scale
faults, which Pearson correlation cannot see because it is invariant to both) are tested for
every sensor with correlated peers, not only for the uncertain ones. ``strict=True`` is the
thesis's description: patterns only for uncertain sensors, only ``stuck`` and ``drift``.

Bad input, defined here and in docs/diagnosis.md: a column holding any NaN (the signal had
not started, fell silent, or was never finite) is *unjudged* for this window and takes no
part in anybody's correlated set; a column that is constant in the first part has no
correlation and is unjudged too (it cannot be told from a healthy idle sensor); a window with
fewer rows than ``window`` is not judged at all.

Cost per window (measured in docs/benchmarks.md): the smoothing is ``O(m n)``, the two
correlation matrices ``O(m n p)`` with ``p`` peers per signal (``n`` for all pairs, ``k``
with references), the residual tests ``O(m n p)`` as well; memory ``O(m n p)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

FAULTY_PATTERNS = frozenset({"stuck", "drift", "deviation", "correlation_change"})
"""Patterns that make a sensor faulty; ``ok``, ``uncertain`` and ``unjudged`` do not."""


@dataclass(frozen=True, slots=True)
class SfddSettings:
    """How one window is judged; the defaults suit signals sampled at 10 Hz.

    ``window`` rows of which the first ``split`` share is for correlation; ``smoothing``
    samples of moving average; ``correlation`` is the ``|r|`` above which two sensors are
    correlated on the first part, ``hold`` the ``|r|`` (signed with ``signed``) a correlated
    pair must keep on the second part; ``change`` (Biswas) instead flags a pair whose
    correlation moved by ``change_threshold`` or more. ``stuck_ratio``: a sensor is stuck when
    its spread on the second part is at most this share of its spread on the first.
    ``sigmas``: residual thresholds in standard deviations of the first part's residual;
    ``spread_ratio``: residual spread growth that counts as deviation.
    """

    window: int = 100
    split: float = 0.5
    smoothing: int = 3
    correlation: float = 0.8
    hold: float = 0.5
    signed: bool = False
    references: tuple[str, ...] = ()
    change: bool = False
    change_threshold: float = 0.5
    stuck_ratio: float = 0.05
    sigmas: float = 4.0
    spread_ratio: float = 3.0
    strict: bool = False

    def __post_init__(self) -> None:
        problem = self.problem()
        if problem:
            raise ValueError(problem)

    def problem(self) -> str | None:
        if self.window < 8:
            return f"window must be at least 8 samples, got {self.window}"
        if not 0.2 <= self.split <= 0.8:
            return f"split must be within [0.2, 0.8], got {self.split}"
        first = int(self.window * self.split)
        if min(first, self.window - first) < 4:
            return "each part of the window needs at least 4 samples"
        if not 1 <= self.smoothing <= first:
            return f"smoothing must be within [1, {first}] samples, got {self.smoothing}"
        if not 0.0 < self.correlation < 1.0:
            return f"correlation must be within (0, 1), got {self.correlation}"
        if not 0.0 <= self.hold <= self.correlation:
            return f"hold must be within [0, correlation], got {self.hold}"
        if not 0.0 < self.change_threshold <= 2.0:
            return f"change_threshold must be within (0, 2], got {self.change_threshold}"
        if not 0.0 <= self.stuck_ratio < 1.0:
            return f"stuck_ratio must be within [0, 1), got {self.stuck_ratio}"
        if self.sigmas <= 0 or self.spread_ratio <= 1.0:
            return "sigmas must be > 0 and spread_ratio > 1"
        return None

    @property
    def first(self) -> int:
        """Rows of the correlation part."""
        return int(self.window * self.split)


@dataclass(frozen=True, slots=True)
class SignalVerdict:
    """What one window says about one signal.

    ``pattern`` is ``ok``, ``stuck``, ``drift``, ``deviation``, ``correlation_change``,
    ``uncertain`` (correlations broke, no fault pattern) or ``unjudged`` (``reason`` says
    why). ``peers`` are the signals correlated with it on the first part.
    """

    name: str
    pattern: str
    reason: str = ""
    peers: tuple[str, ...] = ()
    values: dict[str, float] = field(default_factory=dict)

    @property
    def faulty(self) -> bool:
        return self.pattern in FAULTY_PATTERNS


def _smooth(h: Array, k: int) -> Array:
    """Moving average of ``k`` rows (``m - k + 1`` rows out); NaN stays NaN."""
    if k <= 1:
        return h
    c = np.cumsum(np.vstack([np.zeros((1, h.shape[1])), h]), axis=0)
    out: Array = (c[k:] - c[:-k]) / k
    return out


def _flat(sd: Array, mean: Array) -> npt.NDArray[np.bool_]:
    """A spread indistinguishable from rounding: the signal is constant."""
    flat: npt.NDArray[np.bool_] = sd <= 1e-9 * (1.0 + np.abs(mean))
    return flat


def _corr(za: Array, zb: Array) -> Array:
    """Pearson correlation of standardised columns: ``za.T @ zb / rows``."""
    out: Array = za.T @ zb / za.shape[0]
    return out


class SfddDetector:
    """Judges windows of ``names`` signals. Pure: :meth:`judge` takes the window matrix."""

    def __init__(self, names: Sequence[str], settings: SfddSettings | None = None) -> None:
        self.names = tuple(names)
        self.settings = settings or SfddSettings()
        if len(set(self.names)) != len(self.names):
            raise ValueError("signal names must be unique")
        unknown = [r for r in self.settings.references if r not in self.names]
        if unknown:
            raise ValueError(f"reference signal {unknown[0]!r} is not one of the signals")
        self._ref_index = np.array([self.names.index(r) for r in self.settings.references],
                                   dtype=np.intp)

    def judge(self, window: npt.ArrayLike) -> list[SignalVerdict]:
        """One verdict per signal for a ``(rows, signals)`` window, oldest row first.

        Only the last ``settings.window`` rows are used; fewer rows judge nothing.
        """
        s = self.settings
        h = np.asarray(window, dtype=np.float64)
        n = len(self.names)
        if h.ndim != 2 or h.shape[1] != n:
            raise ValueError(f"window must have shape (rows, {n}), got {h.shape}")
        if h.shape[0] < s.window:
            why = f"window not full ({h.shape[0]} of {s.window} samples)"
            return [SignalVerdict(name, "unjudged", why) for name in self.names]
        h = h[-s.window:]
        finite: npt.NDArray[np.bool_] = np.asarray(np.isfinite(h).all(axis=0))
        hs = _smooth(np.where(np.isfinite(h), h, 0.0), s.smoothing)
        first = s.first - s.smoothing + 1
        a, b = hs[:first], hs[first:]
        mu_a, sd_a = a.mean(axis=0), a.std(axis=0)
        mu_b, sd_b = b.mean(axis=0), b.std(axis=0)
        flat_a = _flat(sd_a, mu_a)
        usable = finite & ~flat_a
        safe_a = np.where(usable, sd_a, 1.0)
        za = (a - mu_a) / safe_a
        moving_b = ~_flat(sd_b, mu_b)
        safe_b = np.where(moving_b, sd_b, 1.0)
        zb = (b - mu_b) / safe_b

        peers = self._ref_index if len(self._ref_index) else np.arange(n, dtype=np.intp)
        r_a = _corr(za, za[:, peers])                      # (n, p)
        r_b = _corr(zb, zb[:, peers])
        valid = usable[:, None] & usable[peers][None, :]
        valid &= np.arange(n)[:, None] != peers[None, :]
        both_move = moving_b[:, None] & moving_b[peers][None, :]
        if s.change:
            # Biswas: every defined pair is watched; a pair breaks when its correlation moves.
            pair = valid
            broken = pair & (~both_move | (np.abs(r_b - r_a) >= s.change_threshold))
        else:
            pair = valid & (np.abs(r_a) >= s.correlation)
            held = (np.sign(r_a) * r_b >= s.hold) if s.signed else (np.abs(r_b) >= s.hold)
            broken = pair & (~both_move | ~held)

        # Regression of each signal on each peer, fitted on the first part (i ~ c + g * j).
        gain = r_a * sd_a[:, None] / np.where(usable, sd_a, 1.0)[peers][None, :]
        icpt = mu_a[:, None] - gain * mu_a[peers][None, :]
        sigma = sd_a[:, None] * np.sqrt(np.clip(1.0 - r_a ** 2, 0.0, None))
        # A residual below 2 % of the signal's own spread is no fault worth a verdict (it
        # keeps noise-free, exactly related signals from alarming on rounding).
        sigma = np.maximum(sigma, 0.02 * np.where(usable, sd_a, 1.0)[:, None])
        resid = b[:, :, None] - (icpt[None] + gain[None] * b[:, peers][:, None, :])  # (mb, n, p)
        mb = b.shape[0]
        t = np.arange(mb, dtype=np.float64) - (mb - 1) / 2.0
        slope = np.einsum("t,tnp->np", t, resid) / float(np.dot(t, t))
        trend = np.abs(slope) * (mb - 1) / sigma
        shift = np.abs(resid.mean(axis=0)) / sigma
        spread = resid.std(axis=0) / sigma
        # Residual tests only where a regression means something: correlated pairs.
        correlated = valid & (np.abs(r_a) >= s.correlation)
        drifting = correlated & (trend >= s.sigmas)
        deviating = correlated & ((shift >= s.sigmas) | (spread >= s.spread_ratio))

        disagree = broken if s.strict else broken | drifting | deviating
        agree = pair & ~disagree
        count = pair.sum(axis=1)
        denom = np.maximum(disagree.sum(axis=1), 1)
        # Cleared as a response of the system when some correlated signal still agrees.
        suspect: npt.NDArray[np.bool_] = np.asarray(disagree.any(axis=1) & ~agree.any(axis=1))
        broken_f = broken.sum(axis=1) / np.maximum(count, 1)
        drift_f = (disagree & drifting).sum(axis=1) / denom
        dev_f = (disagree & deviating).sum(axis=1) / denom
        ratio_b = np.where(usable, sd_b / safe_a, 1.0)
        stuck_self: npt.NDArray[np.bool_] = np.asarray(ratio_b <= s.stuck_ratio)
        peer_stuck = stuck_self[peers][None, :] & pair
        moving_peers = (pair & ~peer_stuck).sum(axis=1)
        peers_still: npt.NDArray[np.bool_] = np.asarray(moving_peers > peer_stuck.sum(axis=1))

        out: list[SignalVerdict] = []
        for i, name in enumerate(self.names):
            if not finite[i]:
                out.append(SignalVerdict(name, "unjudged", "no finite sample in part of the "
                                         "window (not started, silent or non-finite values)"))
                continue
            if flat_a[i]:
                out.append(SignalVerdict(name, "unjudged", "constant on the correlation part: "
                                         "no correlation defined"))
                continue
            mine = tuple(self.names[int(j)] for j in peers[pair[i]])
            if not mine:
                out.append(SignalVerdict(name, "unjudged", "no correlated signal on the "
                                         "correlation part", values={"peers": 0.0}))
                continue
            values = {"peers": float(count[i]), "broken": float(broken_f[i]),
                      "trend_sigmas": float(np.max(np.where(pair[i], trend[i], 0.0))),
                      "shift_sigmas": float(np.max(np.where(pair[i], shift[i], 0.0))),
                      "spread_ratio": float(np.max(np.where(pair[i], spread[i], 0.0))),
                      "spread_b_over_a": float(ratio_b[i])}
            if stuck_self[i] and peers_still[i]:
                pattern, why = "stuck", "no change while its correlated signals moved"
            elif not suspect[i]:
                pattern, why = "ok", ("correlations hold" if not disagree[i].any() else
                                      "cleared: a correlated signal behaves the same")
            elif drift_f[i] > 0.5:
                pattern, why = "drift", "its residual against its correlated signals trends"
            elif s.change and broken[i].any():
                pattern, why = "correlation_change", "its correlations changed"
            elif not s.strict and dev_f[i] > 0.5:
                pattern, why = "deviation", "it no longer follows its correlated signals"
            else:
                pattern, why = "uncertain", "correlations broke without a fault pattern"
            out.append(SignalVerdict(name, pattern, why, mine, values))
        return out


__all__ = ["FAULTY_PATTERNS", "SfddDetector", "SfddSettings", "SignalVerdict"]
