"""The black box on another computer over a thin link: false alarms and link use.

The real thesis robot in one network namespace, the black box (``blackbox run``, the
thesis's ten observers) in another, joined by a veth pair shaped with ``tc tbf`` (default
8 Mbit/s, about the thesis's Wi-Fi). The robot is healthy throughout, so every alarm
(episode of faulty observations after a settle) is a false alarm. Two runs: rates from the
publishers' counters (the default) and subscriptions only (``?counters=0``, what the
thesis's black box did). Reports false alarms per hour, by observer, and the bytes the black
box's end of the link received and sent.

Run as root: .venv/bin/python benchmarks/constrained_link.py [--seconds 120] [--rate 8mbit]
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from blackbox.app import DEFAULT_CONFIG
from netns_link import (
    WIFI_RATE,
    read_lines,
    robot_in,
    shaped_link,
    start_black_box,
    why_not,
)

SETTLE = 10.0


def episodes(obs: list[dict[str, object]], since: float) -> Counter[str]:
    """Alarms (maximal runs of faulty observations of one observer key) after ``since``."""
    on: dict[str, bool] = {}
    count: Counter[str] = Counter()
    for o in sorted(obs, key=lambda o: float(o["time"])):  # type: ignore[arg-type]
        res = o["resource"]
        assert isinstance(res, dict)
        key = f"{o['observer']} {res.get('node') or res.get('topic')}"
        faulty = bool(o["faulty"]) and float(o["time"]) >= since  # type: ignore[arg-type]
        if faulty and not on.get(key, False):
            count[key] += 1
        on[key] = faulty
    return count


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="seconds per run")
    parser.add_argument("--rate", default=WIFI_RATE, help="tc tbf rate of the link")
    args = parser.parse_args()
    reason = why_not()
    if reason is not None:
        print(f"skipped: {reason}")
        return 0
    print(f"machine: {platform.machine()}, {platform.processor() or '?'}, "
          f"python {platform.python_version()}; link {args.rate} (tc tbf, both directions); "
          f"{args.seconds:g} s per run, first {SETTLE:g} s not counted")
    rows = []
    with tempfile.TemporaryDirectory() as tmp, shaped_link(args.rate) as link, \
            robot_in(link, Path(tmp) / "robot"):
        for label, counters in (("rates from counters (default)", True),
                                ("subscriptions only (?counters=0)", False)):
            out = Path(tmp) / ("on" if counters else "off")
            out.mkdir()
            before = link.box_bytes()
            box = start_black_box(link, DEFAULT_CONFIG, out, args.seconds, counters=counters)
            box.wait(timeout=args.seconds + 60)
            after = link.box_bytes()
            obs = read_lines(out / "obs.jsonl")
            events = read_lines(out / "events.jsonl")
            start = next(float(e["time"]) for e in events if e["kind"] == "start")
            alarms = episodes(obs, start + SETTLE)
            hours = (args.seconds - SETTLE) / 3600.0
            rx = (after[0] - before[0]) * 8 / args.seconds / 1e6
            tx = (after[1] - before[1]) * 8 / args.seconds / 1e6
            behind = sorted({str(e["component"]) for e in events if e["kind"] == "ros1_behind"})
            rows.append((label, sum(alarms.values()), sum(alarms.values()) / hours, rx, tx,
                         ", ".join(f"{k} x{n}" for k, n in alarms.most_common()) or "-",
                         ", ".join(behind) or "-"))
    print("\n| set-up | false alarms | per hour | link in (Mbit/s) | link out (Mbit/s) | "
          "alarms | said it could not keep up with |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]:.0f} | {r[3]:.3f} | {r[4]:.3f} | {r[5]} | {r[6]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
