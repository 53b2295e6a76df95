"""Diagnosis benchmarks: re-diagnosis latency, HS-DAG vs PySAT Hitman, DXC scores.

Run from the repository root: ``.venv/bin/python benchmarks/diagnosis.py [--quick]``.
Prints Markdown tables (the numbers in docs/benchmarks.md (section Diagnosis) come from here).
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from collections import Counter
from pathlib import Path

from pysat.examples.hitman import Hitman

from blackbox.diagnose.dxc import (
    BASELINES,
    CircuitDiagnoser,
    load_catalog,
    load_scenario,
    score,
)
from blackbox.diagnose.dxc_audit import audit
from blackbox.diagnose.engine import DiagnosisEngine
from blackbox.diagnose.hsdag import minimal_hitting_sets
from blackbox.diagnose.robot_model import NodeSpec, ObservationSpec, RobotModel
from blackbox.model import Code, Observation, Resource

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / "data" / "shared"


def observe(engine: DiagnosisEngine, failed: set[tuple[str, str]], t: float
            ) -> list[Observation]:
    return [Observation(t, s.type, s.resource,
                        Code.NO_STATE_FITS if (s.type, s.resource.node or s.resource.topic)
                        in failed else Code.GENERAL_OK)
            for s in engine.model.observations]


def timed_updates(engine: DiagnosisEngine, states: list[set[tuple[str, str]]], rounds: int
                  ) -> tuple[list[float], list]:
    times, results = [], []
    t = 0.0
    for _ in range(rounds):
        for failed in states:
            t += 1.0
            obs = observe(engine, failed, t)
            t0 = time.perf_counter()
            d = engine.update(t, obs)
            times.append(time.perf_counter() - t0)
            results.append(d)
    return times, results


def thesis_latency(rounds: int) -> None:
    model = SHARED / "reference/thesis-setup/diagnosis_model.yaml"
    kill = {("activated", "/usb_cam"), ("hz", "/usb_cam/image_raw"),
            ("timeout", "/usb_cam/image_raw")}
    states = [set(), kill, {("scores", "/signal")}, kill | {("hz", "/audio")}]
    print("\n### Re-diagnosis latency, thesis model (3 nodes, 3 topics, 10 observations)\n")
    print("| mode | updates | median ms | p95 ms | max ms |")
    print("|---|---|---|---|---|")
    for label, cache in (("cold (result cache off)", 0), ("with result cache", 256)):
        engine = DiagnosisEngine.from_model_file(model, cache_size=cache)
        times, _ = timed_updates(engine, states, rounds)
        times = sorted(times[len(states):])  # first round builds nothing special but skip it
        print(f"| {label} | {len(times)} | {statistics.median(times) * 1e3:.3f} | "
              f"{times[int(0.95 * len(times))] * 1e3:.3f} | {times[-1] * 1e3:.3f} |")


def generated_model(n: int, rng: random.Random) -> RobotModel:
    """Layered pipelines: node i publishes /t{i}, subscribes 0-2 topics of earlier nodes;
    every node has activated, every topic hz and timeout, every fifth a scores observer."""
    nodes, obs = [], []
    for i in range(n):
        k = 0 if i < max(2, n // 20) else rng.randint(1, 2)
        subs = tuple(sorted({f"/t{rng.randrange(max(0, i - 30), i)}" for _ in range(k)}))
        nodes.append(NodeSpec(f"/n{i}", (f"/t{i}",), subs))
        obs.append(ObservationSpec("activated", Resource(node=f"/n{i}")))
        obs.append(ObservationSpec("hz", Resource(topic=f"/t{i}")))
        obs.append(ObservationSpec("timeout", Resource(topic=f"/t{i}")))
        if i % 5 == 0:
            obs.append(ObservationSpec("scores", Resource(topic=f"/t{i}")))
    return RobotModel(tuple(nodes), tuple(obs))


def symptoms(model: RobotModel, dead: set[str]) -> set[tuple[str, str]]:
    """Dead nodes fail activated; their topics and everything downstream stop (hz, timeout)."""
    silent: set[str] = set()
    order = sorted(model.nodes, key=lambda s: int(s.name[2:]))
    for node in order:
        if node.name in dead or any(t in silent for t in node.sub):
            silent.update(node.pub)
    failed = {("activated", n) for n in dead}
    for t in silent:
        failed |= {("hz", t), ("timeout", t)}
    return failed


def generated_times(n: int, repeats: int, rng: random.Random | None = None
                    ) -> list[tuple[int, int, float, float, bool, bool]]:
    """Re-diagnosis after 1-5 dead nodes on a generated model, ``repeats`` engines per fault
    count, each first fed all-OK observations: per update ``(faults, failed observations,
    wall seconds, CPU seconds, top candidate = injected, complete)``."""
    rng = rng if rng is not None else random.Random(42)
    model = generated_model(n, rng)
    out = []
    for k in range(1, 6):
        for _ in range(repeats):
            engine = DiagnosisEngine(model, cache_size=0, time_budget=1.0)
            engine.update(0.0, observe(engine, set(), 0.0))
            dead = set(rng.sample([s.name for s in model.nodes], k))
            failed = symptoms(model, dead)
            obs = observe(engine, failed, 1.0)
            c0, t0 = time.process_time(), time.perf_counter()
            d = engine.update(1.0, obs)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            out.append((k, len(failed), wall, cpu,
                        bool(d and d.candidates and set(d.candidates[0]) == dead),
                        bool(d and d.complete)))
    return out


def generated_latency(sizes: list[int], repeats: int) -> None:
    print("\n### Re-diagnosis latency, generated robot models (dead nodes, downstream topics "
          "silent)\n")
    print("| nodes | faults | failed obs | median ms | max ms | top candidate = injected | "
          "complete |")
    print("|---|---|---|---|---|---|---|")
    rng = random.Random(42)
    for n in sizes:
        rows = generated_times(n, repeats, rng)
        for k in range(1, 6):
            mine = [r for r in rows if r[0] == k]
            times = [r[2] for r in mine]
            print(f"| {n} | {k} | {statistics.median(r[1] for r in mine):.0f} | "
                  f"{statistics.median(times) * 1e3:.2f} | {max(times) * 1e3:.2f} | "
                  f"{sum(r[4] for r in mine)}/{repeats} | {sum(r[5] for r in mine)}/{repeats} |")


def hitman_comparison(bound: float) -> None:
    print("\n### HS-DAG vs PySAT Hitman (all minimal hitting sets, same conflicts)\n")
    print("| conflicts | elements | size | hitting sets | HS-DAG nodes | HS-DAG ms | Hitman ms | "
          "Hitman / HS-DAG |")
    print("|---|---|---|---|---|---|---|---|")
    rng = random.Random(3)
    for count, universe, lo, hi in ((10, 15, 2, 4), (20, 25, 2, 5), (25, 30, 2, 4),
                                    (15, 40, 3, 5)):
        family = [rng.sample(range(universe), rng.randint(lo, hi)) for _ in range(count)]
        t0 = time.perf_counter()
        ours = minimal_hitting_sets(family, deadline=t0 + bound)
        t_ours = time.perf_counter() - t0
        t0 = time.perf_counter()
        theirs, timed_out = set(), False
        with Hitman(bootstrap_with=family, htype="sorted") as h:
            for hs in h.enumerate():
                theirs.add(frozenset(hs))
                if time.perf_counter() - t0 > bound:
                    timed_out = True
                    break
        t_hit = time.perf_counter() - t0
        same = "" if timed_out or not ours.complete or set(ours.sets) == theirs else " (DIFFER)"
        note = " (bounded)" if timed_out or not ours.complete else ""
        print(f"| {count} | {universe} | {lo}-{hi} | {len(ours.sets)}{same}{note} | "
              f"{ours.nodes} | {t_ours * 1e3:.1f} | {t_hit * 1e3:.1f} | {t_hit / t_ours:.2f} |")


def dxc_scores(limit: float, models: list[str]) -> None:
    print(f"\n### DX Competition circuits ({limit:g} s per scenario, one core)\n")
    print("| model | gates | scored | mean score (best) | min (best) | mean score (all) | "
          "injected faults, for reference | time limit hit | slowest s | baselines (issue) | "
          "ground truth audit | mean (best) where the truth agrees |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    root = SHARED / "benchmarks/dxc"
    for m in models:
        d = CircuitDiagnoser(load_catalog(root / f"models/{m}.xml"))
        f = len(d.circuit.gates)
        best, every, injected, stopped, slowest = [], [], [], 0, 0.0
        verdicts: Counter[str] = Counter()
        agreeing: list[float] = []
        for path in sorted((root / f"scenarios/{m}").glob("*.scn")):
            scenario = load_scenario(path)
            r = d.run(scenario, limit, "best")
            r_all = d.run(scenario, limit, "all")
            stopped += (not r.complete) + (not r_all.complete)
            slowest = max(slowest, r.seconds, r_all.seconds)
            if r.score is None or r_all.score is None:
                continue
            best.append(r.score)
            every.append(r_all.score)
            verdict = audit(d, scenario).verdict
            verdicts[verdict] += 1
            if verdict == "agrees":
                agreeing.append(r.score)
            truth = scenario.ambiguity_group or ()
            injected.append(score([frozenset().union(*scenario.injected)], truth, f,
                                  scenario.normalization or 1.0))
        base = ", ".join(f"{k} {v:.3f}" for k, v in BASELINES.get(m, {}).items()) or "-"
        print(f"| {m} | {f} | {len(best)} | {statistics.mean(best):.3f} | {min(best):.3f} | "
              f"{statistics.mean(every):.3f} | {statistics.mean(injected):.3f} | {stopped} | "
              f"{slowest:.3f} | {base} | "
              f"{', '.join(f'{k} {v}' for k, v in verdicts.most_common())} | "
              f"{statistics.mean(agreeing):.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer repetitions, small models")
    args = ap.parse_args()
    thesis_latency(rounds=50 if args.quick else 500)
    generated_latency([50, 200] if args.quick else [50, 200, 1000], 3 if args.quick else 5)
    hitman_comparison(bound=5.0)
    dxc_scores(1.0, ["74L85"] if args.quick else ["74182", "74L85", "74283", "74181", "c432"])


if __name__ == "__main__":
    main()
