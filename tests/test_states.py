"""States: parsing, which states fit, the resulting observation code, errors."""

from __future__ import annotations

import pytest

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.model import Code, State
from blackbox.observe.base import Summary
from blackbox.observe.states import (
    describe_states,
    evaluate_states,
    fitting_states,
    parse_states,
    states_code,
)

HZ_STATES = """
states:
  - number: 1
    name: ok
    period:
      value: {type: gauss, mean: 0.0667, std_deviation: 0.01}
  - number: 2
    name: slow
    period:
      type: nominal_value
      value: {type: greater_than, greater_than: 0.07}
  - number: 3
    state: steady
    period:
      deviation: [{type: less_than, less_than: 0.001}]
"""


def states(text: str, quantities=("period",)):
    return parse_states(ConfigNode.parse(text, "x.yaml").get("states"), quantities)


def test_parses_numbers_names_and_checks():
    specs = states(HZ_STATES)
    assert [(s.number, s.name) for s in specs] == [(1, "ok"), (2, "slow"), (3, "steady")]
    assert [s.state for s in specs] == [State(1, "ok"), State(2, "slow"), State(3, "steady")]


def test_all_fitting_states_are_reported_in_order():
    specs = states(HZ_STATES)
    # |0.072 - 0.0667| = 0.0053 < 0.01 (ok), 0.072 > 0.07 (slow), 0.0005 < 0.001 (steady)
    assert fitting_states(specs, {"period": Summary(0.072, 0.0005, 50)}) == (
        State(1, "ok"), State(2, "slow"), State(3, "steady"))
    # only ok: 0.066 is not > 0.07 and the deviation 0.002 is not < 0.001
    assert fitting_states(specs, {"period": Summary(0.066, 0.002, 50)}) == (State(1, "ok"),)


def test_no_fitting_state_is_no_state_fits():
    specs = states(HZ_STATES)
    # |0.05 - 0.0667| = 0.0167 >= 0.01, 0.05 <= 0.07, 0.01 >= 0.001
    code, fitting = evaluate_states(specs, {"period": Summary(0.05, 0.01, 50)})
    assert (code, fitting) == (Code.NO_STATE_FITS, ())
    code, fitting = evaluate_states(specs, {"period": Summary(0.066, 0.002, 50)})
    assert (code, fitting) == (Code.GENERAL_OK, (State(1, "ok"),))


def test_a_quantity_without_summary_fits_no_state_that_checks_it():
    specs = states(HZ_STATES)
    assert fitting_states(specs, {"period": None}) == ()
    assert fitting_states(specs, {}) == ()


RESOURCE_STATES = """
states:
  - number: 1
    name: normal
    cpu: {value: {type: less_than, less_than: 50}}
    memory: {value: {type: less_than, less_than: 1000000}}
  - number: 2
    name: busy
    cpu: {value: {type: greater_than, greater_than: 40}}
"""


def test_several_quantities_must_all_pass_and_unchecked_ones_are_free():
    specs = states(RESOURCE_STATES, ("cpu", "memory"))
    calm = {"cpu": Summary(45.0, None, 1), "memory": Summary(5e5, None, 1)}
    assert fitting_states(specs, calm) == (State(1, "normal"), State(2, "busy"))
    hungry = {"cpu": Summary(45.0, None, 1), "memory": Summary(2e6, None, 1)}
    assert fitting_states(specs, hungry) == (State(2, "busy"),)
    # busy does not check memory, so a missing memory summary does not matter to it
    assert fitting_states(specs, {"cpu": Summary(45.0, None, 1), "memory": None}) == (
        State(2, "busy"),)


def test_no_states_configured_is_always_ok():
    assert states("other: 1\n") == ()
    assert states("states:\n") == ()
    code, fitting = evaluate_states((), {"period": Summary(1.0, None, 1)})
    assert (code, fitting) == (Code.GENERAL_OK, ())
    assert states_code((), ()) is Code.GENERAL_OK
    assert describe_states(()) == "no states: always GENERAL_OK"


def test_an_observer_without_quantities_has_states_that_always_fit():
    specs = states("states:\n  - {number: 0, name: up}\n", ())
    assert fitting_states(specs, {}) == (State(0, "up"),)


def test_an_empty_template_check_accepts_any_value_but_needs_a_summary():
    specs = states("states:\n  - number: 1\n    name: ok\n    period:\n")
    assert fitting_states(specs, {"period": Summary(-5.0, None, 1)}) == (State(1, "ok"),)
    assert fitting_states(specs, {"period": None}) == ()


def test_integer_names_are_accepted_as_text():
    assert states("states:\n  - {number: 7, name: 7, period: }\n")[0].name == "7"


def test_describe_states_lists_each_state_and_its_checks():
    assert describe_states(states(HZ_STATES)) == (
        "state 1 'ok': period: |value - 0.0667| < 0.01\n"
        "state 2 'slow': period: value > 0.07\n"
        "state 3 'steady': period: deviation < 0.001")


@pytest.mark.parametrize(("text", "line", "path", "message"), [
    ("states:\n  - {number: 1, name: a, period: }\n  - {number: 1, name: b, period: }\n",
     3, "states[1].number", "duplicate state number 1 (first used at line 2)"),
    ("states:\n  - number: 1\n    name: ok\n    perod: {value: {type: exact, exact: 1}}\n",
     4, "states[0].perod", "unknown key 'perod'; did you mean 'period'?"),
    ("states:\n  - number: 1\n    name: ok\n", 2, "states[0]",
     "state 1 ('ok') checks nothing; give a check for 'period'"),
    ("states:\n  - name: ok\n    period:\n", 2, "states[0]", "missing required key 'number'"),
    ("states:\n  - number: one\n    name: ok\n    period:\n", 2, "states[0].number",
     "expected an integer"),
    ("states:\n  - number: 1\n    period:\n", 2, "states[0]", "missing required key 'name'"),
    ("states:\n  - number: 1\n    name: ok\n    state: ok\n    period:\n", 4,
     "states[0].state", "'name' and 'state' mean the same; give one"),
    ("states:\n  - number: 1\n    name: off\n    period:\n", 3, "states[0].name",
     "quote it, for example name: 'off'"),
    ("states:\n  - ok\n", 2, "states[0]", "a state is a mapping with 'number', 'name'"),
    ("states: {number: 1}\n", 1, "states", "expected a list"),
    ("states:\n  - number: 1\n    name: ok\n    period: {type: gauss}\n", 4,
     "states[0].period.type", "'gauss' is a value check"),
])
def test_configuration_errors_name_the_place_and_the_problem(text, line, path, message):
    with pytest.raises(ConfigError) as info:
        states(text)
    err = info.value
    assert message in err.message
    assert (err.file, err.line, err.path) == ("x.yaml", line, path)


def test_unknown_keys_in_states_of_an_observer_without_quantities():
    with pytest.raises(ConfigError, match="unknown key 'period'"):
        states("states:\n  - {number: 1, name: up, period: }\n", ())
