"""Filters: hand-computed values, edge cases and configuration errors."""

from __future__ import annotations

import copy
import math
import random
import statistics

import pytest

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.observe.base import FILTERS, Summary
from blackbox.observe.filters import (
    MIN_MAX,
    EwmaFilter,
    KMeansFilter,
    MeanFilter,
    MedianFilter,
    NoFilter,
    Window,
    build_filter,
)


def feed(f, xs):
    for x in xs:
        f.update(x)
    return f


# ---- mean ---------------------------------------------------------------------------------


def test_mean_slides_over_the_last_window_size_samples():
    f = feed(MeanFilter(3), [1.0, 2.0, 3.0, 4.0])
    # window [2, 3, 4]: mean 3; deviations -1, 0, 1 -> (1 + 0 + 1) / (3 - 1) = 1
    assert f.summary() == Summary(3.0, 1.0, 3)


def test_mean_before_any_sample_is_undefined():
    f = MeanFilter(3)
    assert f.get() is None
    assert f.summary() is None
    assert f.deviation() is None
    assert f.count() == 0


def test_mean_of_one_sample_has_no_standard_deviation():
    f = feed(MeanFilter(5), [7.0])
    assert f.summary() == Summary(7.0, None, 1)


def test_mean_of_negative_values():
    f = feed(MeanFilter(4), [-1.0, -3.0, -5.0, -7.0])
    # mean -4; deviations 3, 1, -1, -3 -> 9 + 1 + 1 + 9 = 20 -> std sqrt(20 / 3)
    assert f.get() == -4.0
    assert f.deviation() == pytest.approx(math.sqrt(20 / 3), rel=1e-12)


def test_constant_input_gives_the_exact_value_and_zero_deviation():
    f = feed(MeanFilter(50), [0.1] * 5000)
    assert f.get() == 0.1
    assert f.deviation() == 0.0
    # a window that becomes constant after varying samples is exact as well
    f = feed(MeanFilter(3), [1.0, 2.0, 30.0, 0.1, 0.1, 0.1])
    assert f.get() == 0.1
    assert f.deviation() == 0.0


def test_long_running_sliding_statistics_do_not_drift():
    rng = random.Random(7)
    # a large offset makes naive sum-of-squares cancellation visible
    xs = [1e6 + rng.gauss(0.0, 0.5) for _ in range(20_000)]
    f = feed(MeanFilter(50), xs)
    last = xs[-50:]
    assert f.get() == pytest.approx(statistics.fmean(last), rel=0, abs=1e-9)
    assert f.deviation() == pytest.approx(statistics.stdev(last), rel=1e-7)


def test_window_of_one_sample():
    f = feed(MeanFilter(1), [3.0, -2.0])
    assert f.summary() == Summary(-2.0, None, 1)


# ---- median -------------------------------------------------------------------------------


def test_median_of_an_odd_window_slides():
    f = feed(MedianFilter(3), [5.0, 1.0, 4.0])
    assert f.get() == 4.0  # sorted 1, 4, 5
    f.update(2.0)
    assert f.get() == 2.0  # window 1, 4, 2 -> sorted 1, 2, 4
    f.update(10.0)
    assert f.get() == 4.0  # window 4, 2, 10


def test_median_of_an_even_window_is_the_mean_of_the_middle_two():
    f = feed(MedianFilter(4), [5.0, 1.0, 4.0, 2.0])
    assert f.get() == 3.0  # sorted 1, 2, 4, 5 -> (2 + 4) / 2
    f.update(-6.0)
    assert f.get() == 1.5  # window 1, 4, 2, -6 -> sorted -6, 1, 2, 4 -> (1 + 2) / 2


def test_median_of_a_partly_filled_window():
    f = feed(MedianFilter(5), [3.0, 1.0])
    assert f.summary() == Summary(2.0, math.sqrt(2.0), 2)  # deviations +-1 -> 2 / 1


def test_median_with_duplicates_evicts_the_right_sample():
    f = feed(MedianFilter(3), [2.0, 2.0, 9.0, 2.0, 9.0, 9.0])
    assert f.get() == 9.0  # window 2, 9, 9


# ---- kmeans -------------------------------------------------------------------------------


def test_kmeans_odd_window_odd_k_takes_the_exact_centre():
    f = feed(KMeansFilter(5, 3), [10.0, -2.0, 7.0, 100.0, 4.0])
    # sorted -2, 4, 7, 10, 100 -> central 3: (4 + 7 + 10) / 3 = 7
    assert f.get() == 7.0


def test_kmeans_odd_window_even_k_trims_one_more_from_the_top():
    f = feed(KMeansFilter(5, 2), [10.0, -2.0, 7.0, 100.0, 4.0])
    # n - k = 3, start 3 // 2 = 1: sorted[1:3] = 4, 7 -> 5.5
    assert f.get() == 5.5


def test_kmeans_even_window():
    xs = [6.0, 1.0, 5.0, 2.0, 4.0, 3.0]
    # sorted 1..6; k=2: start (6 - 2) // 2 = 2 -> 3, 4 -> 3.5
    assert feed(KMeansFilter(6, 2), xs).get() == 3.5
    # k=3: start (6 - 3) // 2 = 1 -> 2, 3, 4 -> 3.0
    assert feed(KMeansFilter(6, 3), xs).get() == 3.0


def test_kmeans_with_fewer_samples_than_k_averages_all():
    assert feed(KMeansFilter(5, 3), [1.0, 2.0]).get() == 1.5


def test_kmeans_slides():
    f = feed(KMeansFilter(3, 1), [1.0, 50.0, 3.0])
    assert f.get() == 3.0  # sorted 1, 3, 50 -> centre 3
    feed(f, [-40.0, 70.0, 80.0])
    assert f.get() == 70.0  # window -40, 70, 80


def test_kmeans_with_k_equal_to_window_is_the_mean():
    f = feed(KMeansFilter(4, 4), [1.0, 2.0, 3.0, 10.0])
    assert f.get() == 4.0


def test_kmeans_constant_and_negative_input():
    assert feed(KMeansFilter(10, 4), [0.3] * 37).summary() == Summary(0.3, 0.0, 10)
    assert feed(KMeansFilter(3, 1), [-1.0, -9.0, -5.0]).get() == -5.0


# ---- ewma ---------------------------------------------------------------------------------


def test_ewma_takes_the_first_sample_as_is_then_blends():
    f = feed(EwmaFilter(0.5), [4.0])
    assert f.get() == 4.0
    feed(f, [8.0, 0.0])
    # 4 * 0.5 + 8 * 0.5 = 6; 6 * 0.5 + 0 * 0.5 = 3
    assert f.get() == 3.0
    # no window: deviation over all samples 4, 8, 0 -> mean 4, (0 + 16 + 16) / 2 = 16
    assert f.summary() == Summary(3.0, 4.0, 3)


def test_ewma_with_a_window_restarts_from_the_oldest_sample_of_the_window():
    f = feed(EwmaFilter(0.5, window_size=2), [4.0, 8.0, 0.0])
    # window 8, 0: 8 * 0.5 + 0 * 0.5 = 4; deviation of 8, 0: sqrt(32 / 1)
    assert f.summary() == Summary(4.0, math.sqrt(32.0), 2)


def test_ewma_small_decay_rate_over_a_window():
    f = feed(EwmaFilter(0.25, window_size=3), [100.0, 2.0, 6.0, 10.0])
    # window 2, 6, 10: 2 -> 2 + 0.25 * 4 = 3 -> 3 + 0.25 * 7 = 4.75
    assert f.get() == 4.75


def test_ewma_decay_rate_one_is_the_latest_sample():
    assert feed(EwmaFilter(1.0), [3.0, -7.5]).get() == -7.5


def test_ewma_constant_input_is_exact():
    assert feed(EwmaFilter(0.05), [0.1] * 1000).summary() == Summary(0.1, 0.0, 1000)
    assert feed(EwmaFilter(0.05, 20), [0.1] * 1000).summary() == Summary(0.1, 0.0, 20)


# ---- nofilter -----------------------------------------------------------------------------


def test_nofilter_passes_the_latest_sample_with_deviation_over_all_samples():
    f = feed(NoFilter(), [2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0])
    # mean 5; squared deviations 9 + 1 + 1 + 1 + 0 + 0 + 4 + 16 = 32 -> sqrt(32 / 7)
    assert f.get() == 9.0
    assert f.deviation() == pytest.approx(math.sqrt(32 / 7), rel=1e-12)
    assert f.count() == 8


def test_nofilter_single_and_negative_samples():
    assert feed(NoFilter(), [-3.5]).summary() == Summary(-3.5, None, 1)
    assert feed(NoFilter(MIN_MAX), [3.0, -1.0, 2.0]).summary() == Summary(2.0, 4.0, 3)


# ---- min_max ------------------------------------------------------------------------------


def test_min_max_deviation_slides():
    f = MeanFilter(3, MIN_MAX)
    spreads = []
    for x in [5.0, 1.0, 4.0, 3.0, 2.0, 2.0, 2.0]:
        f.update(x)
        spreads.append(f.deviation())
    # windows: [5] [5,1] [5,1,4] [1,4,3] [4,3,2] [3,2,2] [2,2,2]
    assert spreads == [0.0, 4.0, 4.0, 3.0, 2.0, 1.0, 0.0]


def test_min_max_with_repeated_extremes_matches_the_window():
    rng = random.Random(3)
    w = Window(5, extremes=True)
    seen: list[float] = []
    for _ in range(2000):
        x = float(rng.randint(-2, 2))
        w.push(x)
        seen.append(x)
        assert w.spread() == max(seen[-5:]) - min(seen[-5:])


# ---- behaviour common to all filters -----------------------------------------------------


@pytest.mark.parametrize("make", [
    lambda: MeanFilter(3), lambda: MedianFilter(3), lambda: KMeansFilter(3, 1),
    lambda: EwmaFilter(0.5), lambda: EwmaFilter(0.5, 3), lambda: NoFilter(),
])
def test_non_finite_samples_are_dropped_and_counted(make):
    f = feed(make(), [1.0, math.nan, math.inf, -math.inf, 1.0])
    assert f.get() == 1.0
    assert f.count() == 2
    assert f.rejected == 3


@pytest.mark.parametrize("make", [
    lambda: MeanFilter(3), lambda: MedianFilter(3), lambda: KMeansFilter(3, 2),
    lambda: EwmaFilter(0.5), lambda: EwmaFilter(0.5, 3), lambda: NoFilter(MIN_MAX),
])
def test_reset_forgets_everything(make):
    f = feed(make(), [1.0, 2.0, 3.0, 4.0])
    f.reset()
    assert f.summary() is None
    assert f.count() == 0
    f.update(-2.0)
    assert f.get() == -2.0


def test_median_and_kmeans_agree_with_a_full_sort_on_a_long_stream():
    rng = random.Random(11)
    med, km = MedianFilter(8), KMeansFilter(8, 4)
    seen: list[float] = []
    for _ in range(3000):
        x = float(rng.randint(0, 20))
        med.update(x)
        km.update(x)
        seen.append(x)
        window = sorted(seen[-8:])
        n = len(window)
        if n % 2:
            assert med.get() == window[n // 2]
        else:
            assert med.get() == (window[n // 2 - 1] + window[n // 2]) / 2
        k = min(4, n)
        start = (n - k) // 2
        assert km.get() == pytest.approx(sum(window[start:start + k]) / k)


# ---- configuration ------------------------------------------------------------------------


def parse_filter(text: str):
    return build_filter(ConfigNode.parse(text, "x.yaml").get("filter"))


def filter_error(text: str) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse_filter(text)
    return info.value


def test_every_filter_type_is_registered():
    assert {"mean", "median", "kmeans", "ewma", "nofilter"} <= set(FILTERS)


def test_absent_null_or_empty_filter_is_nofilter():
    assert isinstance(build_filter(None), NoFilter)
    assert isinstance(parse_filter("filter:\n"), NoFilter)
    assert isinstance(parse_filter("filter: {}\n"), NoFilter)


def test_filters_parse_with_their_parameters():
    f = parse_filter("filter: {type: mean, window_size: 50, deviation: std_deviation}")
    assert isinstance(f, MeanFilter) and f.window_size == 50
    f = parse_filter("filter: {type: median, window_size: 7, deviation: min_max}")
    assert isinstance(f, MedianFilter) and f.deviation_type == "min_max"
    f = parse_filter("filter: {type: kmeans, window_size: 50, k_size: 10}")
    assert isinstance(f, KMeansFilter) and (f.window_size, f.k_size) == (50, 10)
    f = parse_filter("filter: {type: ewma, decay_rate: 0.05, window_size: 20}")
    assert isinstance(f, EwmaFilter) and (f.decay_rate, f.window_size) == (0.05, 20)
    f = parse_filter("filter: {type: ewma, decay_rate: 1}")
    assert isinstance(f, EwmaFilter) and f.window_size is None
    assert isinstance(parse_filter("filter: {type: nofilter, deviation: min_max}"), NoFilter)


@pytest.mark.parametrize(("text", "line", "path", "message"), [
    ("filter:\n  type: mean\n  window_size: 0\n", 3, "filter.window_size",
     "window_size must be an integer >= 1, got 0"),
    ("filter:\n  type: mean\n  window_size: -3\n", 3, "filter.window_size",
     "window_size must be an integer >= 1, got -3"),
    ("filter:\n  type: median\n  window_size: 2.5\n", 3, "filter.window_size",
     "window_size must be an integer >= 1, got 2.5"),
    ("filter:\n  type: mean\n  window_size: ten\n", 3, "filter.window_size",
     "window_size must be an integer >= 1, got 'ten'"),
    ("filter:\n  type: mean\n  window_size: true\n", 3, "filter.window_size",
     "window_size must be an integer >= 1, got True"),
    ("filter:\n  type: mean\n", 2, "filter", "missing required key 'window_size'"),
    ("filter:\n  type: kmeans\n  window_size: 5\n  k_size: 6\n", 4, "filter.k_size",
     "k_size must be <= window_size (5), got 6"),
    ("filter:\n  type: kmeans\n  window_size: 5\n  k_size: 0\n", 4, "filter.k_size",
     "k_size must be an integer >= 1, got 0"),
    ("filter:\n  type: kmeans\n  window_size: 5\n", 2, "filter", "missing required key 'k_size'"),
    ("filter:\n  type: ewma\n  decay_rate: 0\n", 3, "filter.decay_rate",
     "decay_rate must be a number in (0, 1], got 0"),
    ("filter:\n  type: ewma\n  decay_rate: 1.5\n", 3, "filter.decay_rate",
     "decay_rate must be a number in (0, 1], got 1.5"),
    ("filter:\n  type: ewma\n  decay_rate: fast\n", 3, "filter.decay_rate",
     "decay_rate must be a number in (0, 1], got 'fast'"),
    ("filter:\n  type: ewma\n  decay_rate: 0.1\n  window_size: 0\n", 4, "filter.window_size",
     "window_size must be an integer >= 1, got 0"),
    ("filter:\n  type: meen\n", 2, "filter.type", "did you mean 'mean'?"),
    ("filter:\n  window_size: 3\n", 2, "filter", "missing required key 'type'"),
    ("filter:\n  type: mean\n  windowsize: 3\n", 3, "filter.windowsize",
     "unknown key 'windowsize'; did you mean 'window_size'?"),
    ("filter:\n  type: nofilter\n  window_size: 3\n", 3, "filter.window_size",
     "unknown key 'window_size'"),
    ("filter:\n  type: mean\n  window_size: 3\n  deviation: minmax\n", 4, "filter.deviation",
     "did you mean 'min_max'?"),
    ("filter: mean\n", 1, "filter", "a filter is a mapping with a 'type'"),
])
def test_configuration_errors_name_the_place_and_the_problem(text, line, path, message):
    err = filter_error(text)
    assert message in err.message
    assert (err.file, err.line, err.path) == ("x.yaml", line, path)


@pytest.mark.parametrize("make", [
    lambda: MeanFilter(3), lambda: MedianFilter(3, MIN_MAX), lambda: KMeansFilter(3, 2),
    lambda: EwmaFilter(0.5), lambda: EwmaFilter(0.5, 3), lambda: NoFilter(MIN_MAX),
])
def test_a_deep_copy_probes_the_next_sample_without_touching_the_original(make):
    f = feed(make(), [1.0, 2.0, 3.0, 4.0])
    before = f.summary()
    probe = copy.deepcopy(f)
    probe.update(100.0)
    assert f.summary() == before
    assert probe.summary() != before
    f.update(100.0)
    assert f.summary() == probe.summary()
