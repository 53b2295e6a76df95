"""Hand-written against learned observers on the real ROS 1 robot (Debian's ROS 1, rospy).

    .venv/bin/python benchmarks/learn_ros1.py [--learn 60] [--healthy 60] [--fault 5] [--gap 8]

Starts ``roscore``, the thesis nodes and a laser driver with a node using its scans
(``scripts/ros1_robot/laser_nodes.py``), learns a configuration for ``--learn`` seconds,
then for each configuration (the shipped thesis observers plus a hand-written value
observer of ``/min_distance``; the same plus a hand-written rate observer of ``/scan``,
the situation of issue 14; and the learned one) runs the black box: ``--healthy``
fault-free seconds (false alarms = episodes of faulty observations), then one fault of
each kind for ``--fault`` seconds, ``--gap`` seconds apart: killed camera driver, stopped
audio driver, ``/signal`` slowed to 5 Hz, and the laser driver publishing ranges 0.5 m too
long at the right rate (``/scan`` is not covered by any hand-written observer; its
consumer's ``/min_distance`` is). Per fault it prints the first faulty observation, the
first-ranked candidate of the first diagnosis, and whether the faulty node was among the
reported candidates during the fault (plus 2 s).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from blackbox.app import DEFAULT_CONFIG, RunOptions
from blackbox.learn import learn_from, render_config, render_model
from blackbox.sources import open_source

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE.parent / "scripts" / "ros1_robot"))
from inject import Injector  # noqa: E402
from robot import ThesisRobot, free_port  # noqa: E402

from conftest import black_box_running  # noqa: E402
from test_learn_ros1 import Collect, start_laser_nodes  # noqa: E402

HAND_EXTRA = """
  - type: scores
    topic: /min_distance
    field: data
    filter: {type: mean, window_size: 10}
    states:
      - number: 1
        name: ok
        score: {value: {type: in_between, lower_bound: 1.9, upper_bound: 2.1}}
"""
SCAN_RATE = """
  - type: hz
    topic: /scan
    filter: {type: mean, window_size: 10}
    states:
      - number: 1
        name: ok
        period: {value: {type: in_between, lower_bound: 0.08, upper_bound: 0.12}}
"""
GRACE = 2.0


def faults(robot: ThesisRobot, injector: Injector
           ) -> list[tuple[str, str, Callable[[], object], Callable[[object], None]]]:
    def offset(value: float) -> Callable[[], object]:
        return lambda: robot.set_param("/laser_driver/offset", value)

    return [
        ("kill /usb_cam", "/usb_cam", lambda: injector.begin("kill", "/usb_cam"),
         lambda f: (injector.end(f),  # type: ignore[arg-type,func-returns-value]
                    robot.wait_registered(["/usb_cam"]))),
        ("stop /audio_capture", "/audio_capture", lambda: injector.begin("stall", "/audio"),
         lambda f: injector.end(f)),  # type: ignore[arg-type]
        ("slow /signal to 5 Hz", "/Signal_generator",
         lambda: injector.begin("rate", "/signal", hz=5.0),
         lambda f: injector.end(f)),  # type: ignore[arg-type]
        ("wrong /scan values", "/laser_driver", offset(0.5), lambda f: offset(0.0)()),
    ]


def run_config(name: str, config: Path, robot: ThesisRobot, healthy: float, length: float,
               gap: float) -> list[str]:
    sink = Collect()
    options = RunOptions(config=config, source=f"ros1://127.0.0.1:{robot.port}", live=False,
                         extra_sinks=[sink])
    injector = Injector(robot)
    spans: list[tuple[str, str, float, float]] = []
    with black_box_running(options):
        time.sleep(5.0)  # first evaluations and windows fill
        quiet_from = time.time()
        time.sleep(healthy)
        quiet_to = time.time()
        for label, node, begin, end in faults(robot, injector):
            t0 = time.time()
            handle = begin()
            time.sleep(length)
            end(handle)
            spans.append((label, node, t0, time.time()))
            time.sleep(gap)
    with sink.lock:
        observations = list(sink.observations)
        diagnoses = list(sink.diagnoses)
    alarms = 0
    last: dict[object, bool] = {}
    for o in observations:
        if quiet_from <= o.time <= quiet_to and o.faulty and not last.get(o.key(), False):
            alarms += 1
        last[o.key()] = o.faulty
    lines = [f"{name}: {alarms} false alarms in {healthy:g} healthy s"]
    for label, node, t0, t1 in spans:
        seen = [o for o in observations if o.faulty and t0 <= o.time <= t1 + GRACE]
        first = min(seen, key=lambda o: o.time) if seen else None
        diag = [d for d in diagnoses if t0 <= d.time <= t1 + GRACE and d.candidates]
        top = sorted(diag[0].candidates[0]) if diag else []
        listed = any(node in c for d in diag for c in d.candidates)
        first_text = (f"{first.observer} {first.resource.label()} after {first.time - t0:.2f} s"
                      if first else "not detected")
        lines.append(f"| {name} | {label} | {first_text} | {', '.join(top) or '-'} | "
                     f"{'yes' if listed else 'no'} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--learn", type=float, default=60.0)
    p.add_argument("--healthy", type=float, default=60.0)
    p.add_argument("--fault", type=float, default=5.0)
    p.add_argument("--gap", type=float, default=8.0)
    args = p.parse_args(argv)
    out = Path(tempfile.mkdtemp(prefix="learn-ros1-"))
    (out / "logs").mkdir()
    robot = ThesisRobot(free_port(), log_dir=out / "logs").start()
    try:
        start_laser_nodes(robot, out / "logs")
        time.sleep(3.0)
        spec = f"ros1://127.0.0.1:{robot.port}"
        learned = learn_from(lambda: open_source(spec), args.learn)
        learned_path = out / "robot.yaml"
        learned_path.write_text(render_config(learned, "ros1-robot", "robot.model.yaml",
                                              "benchmark"))
        (out / "robot.model.yaml").write_text(render_model(learned, "benchmark"))
        hand_path = out / "hand.yaml"
        hand_path.write_text(DEFAULT_CONFIG.read_text() + HAND_EXTRA)
        rate_path = out / "hand-scan-rate.yaml"
        rate_path.write_text(DEFAULT_CONFIG.read_text() + HAND_EXTRA + SCAN_RATE)
        print(f"learned {learned_path} from {args.learn:g} s; notes: {learned.notes}")
        print("| configuration | fault | first faulty observation | first-ranked candidate | "
              "faulty node among candidates |")
        print("|---|---|---|---|---|")
        for name, path in (("hand-written", hand_path),
                           ("hand-written + hz /scan", rate_path),
                           ("learned", learned_path)):
            for line in run_config(name, path, robot, args.healthy, args.fault, args.gap):
                print(line, flush=True)
    finally:
        robot.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
