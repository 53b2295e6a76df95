"""Circuits: the thesis full adder, DXC catalogs and scenarios, the DXC score."""

from __future__ import annotations

from pathlib import Path

import pytest

from blackbox.cli import main
from blackbox.config.node import ConfigError
from blackbox.diagnose.dxc import (
    Circuit,
    CircuitDiagnoser,
    Gate,
    best_diagnosis,
    load_catalog,
    load_scenario,
    score,
    utility,
    utility_matrix,
)
from blackbox.diagnose.dxc_audit import audit, explains, reproduces, simulate, topological_order

DXC = Path(__file__).resolve().parents[1] / "data" / "shared" / "benchmarks" / "dxc"
needs_dxc = pytest.mark.skipif(not DXC.is_dir(), reason="shared DXC benchmark missing")

# Thesis Fig. 4.1: in1(X1)=in1(A1)=a, in2(X1)=in2(A1)=b, carry-in c into X2 and A2.
FULL_ADDER = Circuit("full-adder", (
    Gate("X1", "xor", ("a", "b"), "x1"),
    Gate("X2", "xor", ("x1", "c"), "sum"),
    Gate("A1", "and", ("a", "b"), "a1"),
    Gate("A2", "and", ("c", "x1"), "a2"),
    Gate("O1", "or", ("a2", "a1"), "carry"),
), ("a", "b", "c", "sum", "carry"))


def fs(*names: str) -> frozenset[str]:
    return frozenset(names)


def test_full_adder_minimal_diagnoses():
    # a=1, b=0, c=1 should give sum=0, carry=1; observed sum=1, carry=0.
    # Conflicts {X1, X2} and {X1, A2, O1}; their minimal hitting sets are the diagnoses.
    d = CircuitDiagnoser(FULL_ADDER)
    obs = {"a": True, "b": False, "c": True, "sum": True, "carry": False}
    facts = d.facts(obs)
    assert d.checker.conflict(facts).components in ({"X1", "X2"}, {"X1", "A2", "O1"})
    assert d.checker.consistent(facts, {"X1"})
    assert not d.checker.consistent(facts, {"X2"})
    sets, complete, _ = d.diagnose(obs, limit=5.0)
    assert sets == (fs("X1"),) and complete  # the minimum-cardinality diagnosis

    from blackbox.diagnose.hsdag import hs_dag

    def prover(path):
        c = d.checker.conflict(facts, path)
        return None if c is None else c.components

    assert set(hs_dag(prover).sets) == {fs("X1"), fs("X2", "A2"), fs("X2", "O1")}


def test_full_adder_correct_outputs_need_no_diagnosis():
    d = CircuitDiagnoser(FULL_ADDER)
    sets, complete, _ = d.diagnose({"a": True, "b": False, "c": True, "sum": False,
                                    "carry": True})
    assert sets == (frozenset(),) and complete


def test_utility_hand_computed():
    f = 33
    assert utility(fs("g1"), fs("g1"), f) == 1.0
    # n = 1, nbar = 1, N = 1, Nbar = 32: 1 - 1*2/(33*2) - 1*33/(33*2)
    assert utility(fs("g1"), fs("g2"), f) == pytest.approx(1 - 1 / 33 - 0.5)
    # reporting nothing against one fault: n = 0, nbar = 1, N = 0, Nbar = 33
    assert utility(fs(), fs("g1"), f) == pytest.approx(1 - 34 / 66)
    # n = 1, nbar = 0, N = 2: 1 - 1*3/(33*2)
    assert utility(fs("g1", "g2"), fs("g1"), f) == pytest.approx(1 - 3 / 66)


def test_score_averages_pairs_and_normalises():
    truth = [fs("g1"), fs("g2")]
    mean = (1.0 + (1 - 1 / 33 - 0.5)) / 2
    assert score([fs("g1"), fs("g2")], truth, 33, 1.0) == pytest.approx(mean)
    assert score([fs("g1")], truth, 33, 0.5) == pytest.approx(mean / 0.5)
    assert score([], [fs("g1")], 33, 1.0) == pytest.approx(1 - 34 / 66)  # no fault = {{}}


def test_utility_matrix_matches_the_pairwise_utility():
    ws = [fs("a", "b"), fs(), fs("c")]
    ts = [fs("a"), fs("b", "c", "d")]
    m = utility_matrix(ws, ts, 10)
    assert m.shape == (3, 2)
    for i, w in enumerate(ws):
        for j, t in enumerate(ts):
            assert m[i, j] == pytest.approx(utility(w, t, 10))


def test_best_diagnosis_maximises_the_mean_utility_against_all_candidates():
    # f = 10. {a,b} vs {a,c}: n = nbar = 1, N = 2: 1 - 3/20 - 9/20 = 0.4;
    # vs {d,e}: n = nbar = 2: 1 - 6/30 - 18/30 = 0.2. Means: {a,b} and {a,c} (1 + 0.4 + 0.2)/3,
    # {d,e} (1 + 0.2 + 0.2)/3; the tie goes to name order.
    candidates = [fs("d", "e"), fs("a", "c"), fs("a", "b")]
    assert best_diagnosis(candidates, 10) == fs("a", "b")
    truth = candidates
    norm = score(truth, truth, 10, 1.0)
    assert norm == pytest.approx((3 * 1 + 2 * 0.4 + 4 * 0.2) / 9)  # all pairs of T
    # the central candidate alone scores above 1: 0.5333 / 0.5111
    assert score([fs("a", "b")], truth, 10, norm) == pytest.approx((1.6 / 3) / norm)
    assert score([fs("a", "b")], truth, 10, norm) > 1.0
    assert best_diagnosis([fs("x")], 10) == fs("x")


@needs_dxc
def test_normalization_factor_is_the_score_of_the_ambiguity_group():
    s = load_scenario(DXC / "scenarios/74L85/74L85.000.scn")
    assert s.ambiguity_group == (fs("gate107"), fs("gate97"))
    assert s.injected == (fs("gate107"),)
    assert s.observations["o2"] is False and s.observations["i1"] is True
    assert score(s.ambiguity_group, s.ambiguity_group, 33, s.normalization) == pytest.approx(1.0)


@needs_dxc
def test_catalog_and_scenario_on_74L85():
    circuit = load_catalog(DXC / "models/74L85.xml")
    assert len(circuit.gates) == 33 and len(circuit.ports) == 14
    d = CircuitDiagnoser(circuit)
    scenario = load_scenario(DXC / "scenarios/74L85/74L85.000.scn")
    r = d.run(scenario, report="all")
    assert set(r.diagnoses) == {fs("gate107"), fs("gate97")} and r.minimum == 2
    assert r.score == pytest.approx(1.0)
    # Two symmetric candidates: either alone has the same expected utility as both.
    best = d.run(scenario)
    assert best.diagnoses == (fs("gate107"),) and best.minimum == 2
    assert best.score == pytest.approx(1.0)
    with pytest.raises(ValueError, match="report"):
        d.run(scenario, report="some")


@needs_dxc
def test_scenario_whose_ground_truth_timed_out_is_unscored():
    s = load_scenario(DXC / "scenarios/c432/c432.040.scn")
    assert s.ambiguity_group is None and not s.scored


def test_bad_catalog_and_scenario_errors(tmp_path: Path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<systemCatalog><oops></systemCatalog>")
    with pytest.raises(ConfigError, match="cannot read DXC system catalog"):
        load_catalog(bad)
    scn = tmp_path / "x.scn"
    scn.write_text("sensors @0 { i1 = maybe };\nambiguityGroup @1 diagnoses = { { g } };\n")
    with pytest.raises(ConfigError, match="non-boolean"):
        load_scenario(scn)


@needs_dxc
def test_cli_prints_scores_and_baselines(capsys):
    assert main(["dxc", "--model", "74L85", "--scenarios", "3", "--root", str(DXC)]) == 0
    out = capsys.readouterr().out
    assert "74L85.002" in out and "mean score 1.000 over 3 scored scenarios" in out
    assert "single-fault simulation 0.749" in out and "reporting: best" in out
    assert main(["dxc", "--model", "74L85", "--scenarios", "1", "--report", "all",
                 "--root", str(DXC)]) == 0
    out = capsys.readouterr().out
    assert "reporting: all" in out
    # 74L85.000: both minimum-cardinality diagnoses reported, score 1
    assert any(line.split()[:5] == ["74L85.000", "1.000", "2", "2", "1"]
               for line in out.splitlines())
    assert main(["dxc", "--model", "nope", "--root", str(DXC)]) == 2


@needs_dxc
@pytest.mark.parametrize("model", ["74181", "74L85"])
def test_parsed_netlist_reproduces_every_scenario(model: str):
    # The benchmark's simulator agrees with the netlist as parsed here: the injected gates
    # giving the opposite output yields exactly the sensor values after the injection.
    order = topological_order(load_catalog(DXC / f"models/{model}.xml"))
    files = sorted((DXC / f"scenarios/{model}").glob("*.scn"))
    assert files
    for path in files:
        s = load_scenario(path)
        inputs = {k: v for k, v in s.observations.items() if k.startswith("i")}
        values = simulate(order, inputs, frozenset().union(*s.injected))
        assert {k: values[k] for k in s.observations} == s.observations, s.name


@needs_dxc
def test_score_formula_reproduces_every_normalization_factor_of_74181():
    f = len(load_catalog(DXC / "models/74181.xml").gates)
    for path in sorted((DXC / "scenarios/74181").glob("*.scn")):
        s = load_scenario(path)
        assert s.scored and s.normalization is not None
        mean = float(utility_matrix(s.ambiguity_group, s.ambiguity_group, f).mean())
        assert mean == pytest.approx(s.normalization, rel=1e-6), s.name


def test_simulation_and_weak_fault_explanations_on_the_full_adder():
    order = topological_order(FULL_ADDER)
    assert [g.name for g in order].index("X1") < [g.name for g in order].index("X2")
    healthy = simulate(order, {"a": True, "b": False, "c": True})
    assert healthy["sum"] is False and healthy["carry"] is True
    # Inverting X2 turns the sum around and leaves the carry alone.
    observed = {"a": True, "b": False, "c": True, "sum": True, "carry": True}
    assert reproduces(order, observed, frozenset({"X2"}))
    assert not reproduces(order, observed, frozenset({"X2", "O1"}))
    # Under the weak fault model a superset is still a diagnosis: O1 may behave.
    assert explains(order, observed, frozenset({"X2", "O1"}))
    assert not explains(order, observed, frozenset({"A1", "O1"}))


@needs_dxc
def test_audit_agrees_where_the_published_group_is_the_minimum_cardinality_set():
    d = CircuitDiagnoser(load_catalog(DXC / "models/74L85.xml"))
    a = audit(d, load_scenario(DXC / "scenarios/74L85/74L85.000.scn"))
    assert a.verdict == "agrees" and a.witness is None
    assert a.published == a.found == 2 and a.injected_in_group and a.not_minimal == 0


@needs_dxc
def test_audit_finds_a_smaller_diagnosis_than_the_published_minimum_on_74181_029():
    # The published group claims minimum cardinality 5; inverting the three injected
    # gates reproduces every reading, so the group cannot be the minimum-cardinality set.
    circuit = load_catalog(DXC / "models/74181.xml")
    scenario = load_scenario(DXC / "scenarios/74181/74181.029.scn")
    a = audit(CircuitDiagnoser(circuit), scenario)
    assert a.verdict == "overstated minimum"
    assert (a.published_minimum, a.minimum) == (5, 3)
    assert a.witness == frozenset({"gate167", "gate177", "gate194"}) == a.injected
    assert reproduces(topological_order(circuit), scenario.observations, a.witness)
    assert a.not_minimal == 216 and not a.injected_in_group


@needs_dxc
def test_audit_reports_an_incomplete_group_and_the_cli_summarises(capsys):
    d = CircuitDiagnoser(load_catalog(DXC / "models/74181.xml"))
    a = audit(d, load_scenario(DXC / "scenarios/74181/74181.026.scn"))
    assert a.verdict == "incomplete" and (a.published, a.found) == (6, 24)
    assert a.witness == a.injected == frozenset({"gate181", "gate194", "gate91"})
    assert main(["dxc", "--model", "74L85", "--audit", "--root", str(DXC)]) == 0
    out = capsys.readouterr().out
    assert "agrees: 26, incomplete: 2" in out
    assert any(line.startswith("74L85.022") and "incomplete" in line
               for line in out.splitlines())
