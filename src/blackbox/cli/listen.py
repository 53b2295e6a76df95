"""``blackbox listen``: the live UCMS state of every robot on a DDS domain."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

_COLOUR = {"OPERATIONAL": "\x1b[32m", "DEGRADED": "\x1b[33m", "NOT_OPERATIONAL": "\x1b[31m",
           "UNKNOWN": "\x1b[90m"}
_RESET = "\x1b[0m"


def register(sub: Any) -> None:
    p = sub.add_parser("listen", help="show the live health of every robot on a DDS domain",
                       description=__doc__)
    add_bus_arguments(p)
    p.add_argument("--backfill", type=float, default=600.0, metavar="SECONDS",
                   help="on first sight of a robot, fetch its recorded events of the last "
                        "SECONDS through a log request (0 = off; default 600)")
    p.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                   help="stop after SECONDS (default: until interrupted)")
    p.add_argument("--json", action="store_true",
                   help="print the whole state as one JSON line whenever it changes")
    p.set_defaults(func=run)


def add_bus_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--domain", type=int, default=0, help="DDS domain id (default 0)")
    p.add_argument("--partition", default="blackbox", help="DDS partition (default blackbox)")
    p.add_argument("--cyclone-config", default=None, metavar="XML_OR_URI",
                   help="Cyclone DDS configuration (default: CYCLONEDDS_URI, else loopback)")


def open_bus(args: argparse.Namespace) -> Any:
    from blackbox.transport.participant import Bus, TransportSettings

    try:
        settings = TransportSettings(args.domain, args.partition, args.cyclone_config)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None
    return Bus.open(settings)


def render(state: dict[str, Any], colour: bool) -> str:
    lines = [time.strftime("%H:%M:%S") + f"  robots: {len(state['robots'])}"]
    for name, robot in state["robots"].items():
        lines.append("")
        lines.append(f"robot {name}")
        for ename, entity in sorted(robot["entities"].items()):
            health = entity["health"] if entity["online"] else "UNKNOWN"
            word = health if entity["online"] else f"{health} (offline)"
            if entity["bit"]:
                word += " [BIT]"
            if colour:
                word = _COLOUR.get(health, "") + word + _RESET
            label = "(robot)" if entity["kind"] == "robot" else ename
            lines.append(f"  {label:40} {word}")
        for event in list(robot["events"])[-8:]:
            stamp = time.strftime("%H:%M:%S", time.localtime(event["time"]))
            origin = " [log]" if event["origin"] == "log" else ""
            lines.append(f"  {stamp} {event['kind']:11} {event['entity']}: "
                         f"{event['text']}{origin}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from blackbox.transport.listener import HealthListener

    bus = open_bus(args)
    if bus is None:
        return 2
    listener = HealthListener(bus, backfill=max(0.0, args.backfill))
    tty = sys.stdout.isatty() and not args.json
    end = None if args.duration is None else time.monotonic() + args.duration
    last = ""
    try:
        while end is None or time.monotonic() < end:
            listener.poll(0.2)
            state = listener.to_dict()
            text = json.dumps(state, sort_keys=True)
            if text == last:
                continue
            last = text
            if args.json:
                print(text, flush=True)
            else:
                out = render(state, tty)
                print(("\x1b[2J\x1b[H" + out) if tty else out + "\n", flush=True)
    finally:
        bus.close()
    return 0
