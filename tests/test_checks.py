"""Hypothesis checks: hand-computed t statistics, strict value checks, configuration errors."""

from __future__ import annotations

import math

import pytest

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.observe.base import VALUE_CHECKS, Summary
from blackbox.observe.checks import (
    AcceptAllCheck,
    NominalValueCheck,
    StudentTCheck,
    build_check,
    build_value_check,
)


def check(text: str):
    return build_check(ConfigNode.parse(text, "x.yaml"))


def value_check(text: str):
    return build_value_check(ConfigNode.parse(text, "x.yaml"))


# ---- student_t ----------------------------------------------------------------------------

# Samples 1, 2, ..., 10: mean 5.5; squared deviations sum to 82.5, so the sample standard
# deviation is sqrt(82.5 / 9) = 3.027650 and the standard error 3.027650 / sqrt(10) = 0.957427.
ONE_TO_TEN = Summary(5.5, math.sqrt(82.5 / 9), 10)


def test_student_t_critical_value_matches_the_table():
    assert StudentTCheck(0.0, 0.05).critical_value(10) == pytest.approx(2.262, abs=5e-4)
    assert StudentTCheck(0.0, 0.05).critical_value(5) == pytest.approx(2.776, abs=5e-4)
    assert StudentTCheck(0.0, 0.01).critical_value(10) == pytest.approx(3.250, abs=5e-4)


def test_student_t_statistic_is_computed_by_hand():
    # true mean 3.5: t = (5.5 - 3.5) / 0.957427 = 2.08893
    assert StudentTCheck(3.5, 0.05).statistic(ONE_TO_TEN) == pytest.approx(2.08893, abs=1e-5)
    # true mean 3.3: t = 2.2 / 0.957427 = 2.29782
    assert StudentTCheck(3.3, 0.05).statistic(ONE_TO_TEN) == pytest.approx(2.29782, abs=1e-5)


def test_student_t_fits_when_the_test_does_not_reject():
    assert StudentTCheck(3.5, 0.05).test(ONE_TO_TEN)  # |t| = 2.089 <= 2.262
    assert not StudentTCheck(3.3, 0.05).test(ONE_TO_TEN)  # |t| = 2.298 > 2.262
    assert not StudentTCheck(7.7, 0.05).test(ONE_TO_TEN)  # t = -2.298, two-sided
    assert StudentTCheck(7.5, 0.05).test(ONE_TO_TEN)  # t = -2.089
    # a smaller significance level widens the acceptance region: 2.298 <= 3.250
    assert StudentTCheck(3.3, 0.01).test(ONE_TO_TEN)


def test_student_t_accepts_up_to_and_rejects_beyond_the_critical_value():
    c = StudentTCheck(0.0, 0.05)
    se = 2.0 / math.sqrt(10)
    crit = c.critical_value(10)
    assert c.test(Summary(crit * se * (1 - 1e-9), 2.0, 10))
    assert not c.test(Summary(crit * se * (1 + 1e-9), 2.0, 10))


def test_student_t_with_fixed_std_deviation_ignores_the_window_deviation():
    c = StudentTCheck(0.1, 0.05, std_deviation=0.0003)
    # t = 0.0002 / (0.0003 / sqrt(10)) = 2.108 <= 2.262, although the window deviation
    # 0.00001 alone would give t = 63
    summary = Summary(0.1002, 0.00001, 10)
    assert c.statistic(summary) == pytest.approx(2.10819, abs=1e-4)
    assert c.test(summary)
    assert not StudentTCheck(0.1, 0.05).test(summary)
    assert c.test(Summary(0.1002, None, 10))


def test_student_t_undecidable_cases_do_not_fit():
    assert not StudentTCheck(5.0, 0.05).test(Summary(5.0, None, 1))
    assert not StudentTCheck(5.0, 0.05, std_deviation=1.0).test(Summary(5.0, None, 1))
    assert not StudentTCheck(5.0, 0.05).test(Summary(5.0, None, 4))
    assert StudentTCheck(5.0, 0.05).statistic(Summary(5.0, None, 1)) is None


def test_student_t_on_a_constant_window():
    assert StudentTCheck(5.0, 0.05).test(Summary(5.0, 0.0, 10))
    assert not StudentTCheck(5.0, 0.05).test(Summary(5.000001, 0.0, 10))


def test_student_t_from_configuration():
    c = check("{type: student_t, true_mean: 0.1, significance_level: 0.05, "
              "std_deviation: 0.0003}")
    assert c == StudentTCheck(0.1, 0.05, 0.0003)
    assert "0.1" in c.describe() and "0.0003" in c.describe()


# ---- value checks, at and around their bounds --------------------------------------------


@pytest.mark.parametrize(("text", "passing", "failing"), [
    ("{type: gauss, mean: 15.0, std_deviation: 0.5}",
     [15.0, 15.49, 14.51], [15.5, 14.5, 16.0, 14.0]),
    ("{type: exact, exact: 3}", [3.0], [3.0000001, 2.9999999, -3.0]),
    ("{type: not, exact_not: 3}", [2.9, 3.0000001, -3.0], [3.0]),
    ("{type: greater_than, greater_than: 2}", [2.0001, 100.0], [2.0, 1.9999, -2.5]),
    ("{type: less_than, less_than: 2}", [1.9999, -100.0], [2.0, 2.0001]),
    ("{type: less_than, less_than: -1}", [-1.5], [-1.0, -0.5]),
    ("{type: in_between, lower_bound: 14, upper_bound: 16}",
     [14.001, 15.0, 15.999], [14.0, 16.0, 13.0, 17.0]),
    ("{type: not_in_between, lower_bound: 14, upper_bound: 16}",
     [13.999, 16.001, -20.0], [14.0, 16.0, 15.0]),
])
def test_value_checks_are_strict(text, passing, failing):
    c = value_check(text)
    assert [x for x in passing if c.passes(x)] == passing
    assert [x for x in failing if c.passes(x)] == []
    # as a Check on its own, a value check tests the filtered value
    assert c.test(Summary(passing[0], None, 1))
    assert not c.test(Summary(failing[0], None, 1))


def test_every_value_check_kind_is_registered():
    assert set(VALUE_CHECKS) >= {"gauss", "exact", "not", "greater_than", "less_than",
                                 "in_between", "not_in_between"}


@pytest.mark.parametrize(("text", "description"), [
    ("{type: gauss, mean: 0.0667, std_deviation: 0.01}", "|value - 0.0667| < 0.01"),
    ("{type: exact, exact: 3}", "value == 3"),
    ("{type: not, exact_not: 3}", "value != 3"),
    ("{type: greater_than, greater_than: 2}", "value > 2"),
    ("{type: less_than, less_than: 2}", "value < 2"),
    ("{type: in_between, lower_bound: 14, upper_bound: 16}", "14 < value < 16"),
    ("{type: not_in_between, lower_bound: 14, upper_bound: 16}", "value < 14 or value > 16"),
])
def test_value_checks_describe_their_comparison(text, description):
    assert value_check(text).describe() == description


# ---- nominal_value ------------------------------------------------------------------------

NOMINAL = """
type: nominal_value
value: {type: in_between, lower_bound: 14.0, upper_bound: 16.0}
deviation:
  - {type: less_than, less_than: 0.5}
  - {type: greater_than, greater_than: 0.1}
"""


def test_nominal_value_checks_the_value_and_every_deviation_entry():
    c = check(NOMINAL)
    assert isinstance(c, NominalValueCheck)
    assert c.test(Summary(15.2, 0.3, 50))
    assert not c.test(Summary(16.2, 0.3, 50))  # value out of range
    assert not c.test(Summary(15.2, 0.6, 50))  # first deviation entry fails
    assert not c.test(Summary(15.2, 0.05, 50))  # second deviation entry fails
    assert c.describe() == "14 < value < 16 and deviation < 0.5 and deviation > 0.1"


def test_an_undefined_deviation_fails_deviation_checks_only():
    assert not check(NOMINAL).test(Summary(15.2, None, 1))
    value_only = check("value: {type: gauss, mean: 15.0, std_deviation: 0.5}")
    assert value_only.test(Summary(15.2, None, 1))


def test_nominal_value_type_may_be_omitted():
    c = check("deviation: {type: less_than, less_than: 0.5}")  # a single entry is a list of one
    assert isinstance(c, NominalValueCheck)
    assert c.test(Summary(-1e9, 0.4, 3))
    assert not c.test(Summary(0.0, 0.5, 3))


@pytest.mark.parametrize("text", [
    "", "{}", "{type: nominal_value}", "{type: nominal_value, value: , deviation: }",
    "{value: , deviation: }", "deviation: []",
])
def test_empty_checks_accept_everything_and_say_so(text):
    c = check(text)
    assert isinstance(c, AcceptAllCheck)
    assert c.test(Summary(-1e300, None, 1))
    assert "accepts every value" in c.describe()
    assert isinstance(build_check(None), AcceptAllCheck)


# ---- configuration errors -----------------------------------------------------------------


@pytest.mark.parametrize(("text", "line", "path", "message"), [
    ("c:\n  value:\n    type: gauss\n    mean: 1\n    std_deviation: 0\n", 5,
     "c.value.std_deviation", "std_deviation must be > 0, got 0"),
    ("c:\n  value:\n    type: gauss\n    mean: 1\n    std_deviation: -0.5\n", 5,
     "c.value.std_deviation", "std_deviation must be > 0, got -0.5"),
    ("c:\n  value:\n    type: gauss\n    std_deviation: 1\n", 3, "c.value",
     "missing required key 'mean'"),
    ("c:\n  value:\n    type: in_between\n    lower_bound: 16\n    upper_bound: 14\n", 5,
     "c.value.upper_bound", "upper_bound (14) must be greater than lower_bound (16)"),
    ("c:\n  value:\n    type: not_in_between\n    lower_bound: 2\n    upper_bound: 2\n", 5,
     "c.value.upper_bound", "upper_bound (2) must be greater than lower_bound (2)"),
    ("c:\n  value:\n    type: gaus\n", 3, "c.value.type", "did you mean 'gauss'?"),
    ("c:\n  value:\n    type: greater_than\n    greater_than: high\n", 4,
     "c.value.greater_than", "greater_than must be a finite number, got 'high'"),
    ("c:\n  value:\n    type: exact\n    exact: .nan\n", 4, "c.value.exact",
     "exact must be a finite number"),
    ("c:\n  value:\n    type: less_than\n    less_then: 3\n", 4, "c.value.less_then",
     "unknown key 'less_then'; did you mean 'less_than'?"),
    ("c:\n  value: gauss\n", 2, "c.value", "a value check is a mapping with a 'type'"),
    ("c:\n  deviations: []\n", 2, "c.deviations",
     "unknown key 'deviations'; did you mean 'deviation'?"),
    ("c:\n  type: nominal_value\n  deviations: []\n", 3, "c.deviations",
     "unknown key 'deviations'; did you mean 'deviation'?"),
    ("c:\n  type: student_t\n  true_mean: 1\n  significance_level: 0\n", 4,
     "c.significance_level", "significance_level must be between 0 and 1 (exclusive), got 0"),
    ("c:\n  type: student_t\n  true_mean: 1\n  significance_level: 1\n", 4,
     "c.significance_level", "significance_level must be between 0 and 1 (exclusive), got 1"),
    ("c:\n  type: student_t\n  true_mean: 1\n  significance_level: 0.05\n"
     "  std_deviation: 0\n", 5, "c.std_deviation", "std_deviation must be > 0, got 0"),
    ("c:\n  type: student_t\n  significance_level: 0.05\n", 2, "c",
     "missing required key 'true_mean'"),
    ("c:\n  type: student_t\n  mean: 1\n  significance_level: 0.05\n", 3, "c.mean",
     "unknown key 'mean'"),
    ("c:\n  type: studentt\n", 2, "c.type", "did you mean 'student_t'?"),
    ("c:\n  type: gauss\n  mean: 1\n", 2, "c.type",
     "'gauss' is a value check; put it under 'value:' of a nominal_value check"),
    ("c:\n  true_mean: 1\n", 2, "c", "missing required key 'type' (student_t or nominal_value)"),
    ("c: 0.5\n", 1, "c", "a check is a mapping"),
])
def test_configuration_errors_name_the_place_and_the_problem(text, line, path, message):
    node = ConfigNode.parse(text, "x.yaml")
    with pytest.raises(ConfigError) as info:
        build_check(node["c"])
    err = info.value
    assert message in err.message
    assert (err.file, err.line, err.path) == ("x.yaml", line, path)
