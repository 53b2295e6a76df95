"""The fault draws the simulator and the real diffdrive robots share (review item D2).

``random_campaign`` (``src/blackbox/sources/sim/faults.py``) and the robots' ``schedule``
(``scripts/robots/diffdrive_faults.py``, run by the ROS 1 nodes under Debian's
``/usr/bin/python3`` without the blackbox package) draw their faults from one module of
standard-library code. Sharing it must not move a single draw: every campaign a benchmark,
a test or a documented result used gives the schedule it gave before
(``tests/data/fault_schedules.json``: per campaign the number of faults and a SHA-256 of
the schedule as canonical JSON, recorded from the code before the draws were shared).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import random
import subprocess
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pytest

from blackbox.sources.sim import (
    BUILTIN_ROBOTS,
    THESIS_FAULT_KINDS,
    Topology,
    open_sim,
    random_campaign,
)
from blackbox.sources.sim.faults import _random_params
from blackbox.sources.sim.messages import ScalarModel
from diffdrive_support import SCRIPTS, load_script

robot_faults = load_script(SCRIPTS / "robots" / "diffdrive_faults.py", "diffdrive_faults")

GOLDEN: dict[str, dict[str, dict[str, Any]]] = json.loads(
    (Path(__file__).parent / "data" / "fault_schedules.json").read_text(encoding="utf-8"))
LEARNED_KINDS = ("stuck", "drift", "offset", "scale", "noise", "kill", "stall")
"""``benchmarks/learned_campaign.py``'s kinds."""
REAL_START, REAL_LENGTH = 170.0, 895.0
"""``benchmarks/learned_campaign_real.py`` with its defaults: the schedule starts after 5 s
lead, 30 s start-up, 120 s learning and 15 s settling, and ends 5 s before 900 s."""
PYTHON_OF_ROS1 = Path("/usr/bin/python3")


def canonical(faults: Iterable[Any]) -> list[dict[str, Any]]:
    """A sim ``Fault`` or a robot ``ScheduledFault`` as the golden file hashed it."""
    return [{"kind": f.kind, "component": f.component, "start": f.start, "end": f.end,
             "params": dict(f.params), "field": f.field} for f in faults]


def digest(faults: list[dict[str, Any]]) -> dict[str, Any]:
    text = json.dumps(faults, sort_keys=True)
    return {"faults": len(faults), "sha256": hashlib.sha256(text.encode()).hexdigest()}


@functools.cache
def topology_of(robot: str) -> Topology:
    """One topology per robot: the healthy spreads a noise fault needs are cached per
    topology, so the cases of a robot compute them once."""
    return open_sim(f"sim:{robot}").topology


def simulated(case: str) -> list[dict[str, Any]]:
    """The campaign a golden case names: ``<robot> all kinds 300 s seed N``, ``<robot>
    thesis kinds 300 s seed N`` or ``<robot> learned campaign 900 s seed N``."""
    robot, _, rest = case.partition(" ")
    seed = int(rest.rsplit(" ", 1)[1])
    topology = topology_of(robot)
    if rest.startswith("all kinds"):
        return canonical(random_campaign(topology, 300.0, seed))
    if rest.startswith("thesis kinds"):
        return canonical(random_campaign(topology, 300.0, seed, THESIS_FAULT_KINDS))
    return canonical(random_campaign(topology, 895.0, seed, LEARNED_KINDS, mean_gap=10.0,
                                     warmup=5.0, min_separation=5.0, moving_only=True))


def test_the_golden_file_covers_every_builtin_robot_and_the_real_campaigns_seeds() -> None:
    robots = {case.split(" ", 1)[0] for case in GOLDEN["sim"]}
    assert robots == set(BUILTIN_ROBOTS)
    assert {f"real campaign 900 s seed {s}" for s in range(5)} <= set(GOLDEN["robots"])


@pytest.mark.parametrize("case", sorted(GOLDEN["sim"]))
def test_a_simulated_campaign_draws_the_schedule_it_drew_before(case: str) -> None:
    assert digest(simulated(case)) == GOLDEN["sim"][case], case


def robot_schedules(schedule: Any) -> dict[str, list[dict[str, Any]]]:
    cases = {f"real campaign 900 s seed {seed}": canonical(schedule(seed, REAL_START,
                                                                    REAL_LENGTH))
             for seed in range(10)}
    cases["test_learn_real_faults seed 204"] = canonical(schedule(204, 143.0, 25.0))
    return cases


def test_the_robots_schedules_are_the_ones_drawn_before() -> None:
    drawn = robot_schedules(robot_faults.schedule)
    assert {case: digest(faults) for case, faults in drawn.items()} == GOLDEN["robots"]


@pytest.mark.skipif(not PYTHON_OF_ROS1.exists(), reason="no Debian /usr/bin/python3")
def test_the_ros1_nodes_python_draws_the_same_schedules_without_the_blackbox_package(
        tmp_path: Path) -> None:
    """The ROS 1 nodes import the schedule under Debian's interpreter, isolated from the
    project's environment: it must import without blackbox and draw the same faults."""
    script = (f"import json, sys\nsys.path.insert(0, {str(SCRIPTS / 'robots')!r})\n"
              "import diffdrive_faults as m\n"
              "print(json.dumps([[[f.kind, f.component, f.start, f.end, f.params, f.field]\n"
              f"  for f in m.schedule(s, {REAL_START}, {REAL_LENGTH})] for s in range(5)]))\n"
              "print('blackbox' in sys.modules)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    done = subprocess.run([str(PYTHON_OF_ROS1), "-I", "-c", script], capture_output=True,
                          text=True, timeout=120, cwd=tmp_path, env=env, check=False)
    assert done.returncode == 0, done.stderr
    schedules, imported = done.stdout.splitlines()
    assert imported == "False", "the schedule imported the blackbox package"
    ours = [[[f.kind, f.component, f.start, f.end, dict(f.params), f.field]
             for f in robot_faults.schedule(s, REAL_START, REAL_LENGTH)] for s in range(5)]
    assert json.loads(schedules) == ours


@pytest.mark.parametrize("seed", range(5))
def test_a_simulated_and_a_robot_value_fault_with_the_same_noise_draw_the_same_parameters(
        seed: int) -> None:
    """An offset, drift or scale on a moving signal is drawn in units of its own noise in
    both worlds: the same random state gives the same parameters."""
    topology = topology_of("diffdrive")
    sim_rng, robot_rng = random.Random(seed), random.Random(seed)
    for (topic, name), (sigma, _clean) in robot_faults.FIELDS.items():
        model = ScalarModel(name, 0.0, sigma, "gauss", (("v", 1.0),))
        for kind in ("offset", "drift", "scale"):
            assert _random_params(sim_rng, kind, topology, model) == \
                robot_faults._params(robot_rng, kind, topic, name), (seed, topic, name, kind)
