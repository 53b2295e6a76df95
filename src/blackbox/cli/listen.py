"""``blackbox listen``: the live UCMS state of every robot on a DDS domain, as a table.

Fed by the station's follower (``blackbox.station.follow``) into a throw-away in-memory
station store; on a terminal the table is redrawn in place (rich ``Live``), otherwise it is
printed whenever it changes. ``--json`` prints the whole state as one JSON line per change.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any

STYLE = {"OPERATIONAL": "green", "DEGRADED": "yellow", "NOT_OPERATIONAL": "red",
         "UNKNOWN": "bright_black"}


def register(sub: Any) -> None:
    p = sub.add_parser("listen", help="show the live health of every robot on a DDS domain",
                       description=__doc__)
    add_bus_arguments(p)
    p.add_argument("--backfill", type=float, default=600.0, metavar="SECONDS",
                   help="on first sight of a robot, fetch its recorded events of the last "
                        "SECONDS through a log request (0 = off; default 600)")
    p.add_argument("--stale-after", type=float, default=10.0, metavar="SECONDS",
                   help="show a robot UNKNOWN after SECONDS of silence (default 10)")
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


def transport_settings(args: argparse.Namespace) -> Any:
    """The bus settings of the common arguments, or ``None`` after printing the error."""
    from blackbox.transport.participant import TransportSettings

    try:
        return TransportSettings(args.domain, args.partition, args.cyclone_config)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None


def open_bus(args: argparse.Namespace) -> Any:
    from blackbox.transport.participant import Bus

    settings = transport_settings(args)
    return None if settings is None else Bus.open(settings)


def render(state: dict[str, Any], colour: bool = True) -> Any:
    """The state (``StationFollower.snapshot()``) as a rich renderable: one table per
    robot with its entities in status colours and its latest events. Every text a robot
    chose passes :func:`~blackbox.safetext.terminal_text` (rich lets ESC through)."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    from blackbox.safetext import terminal_text as shown

    parts: list[Any] = [Text(time.strftime("%H:%M:%S") + f"  robots: {len(state['robots'])}"
                             f"  samples: {state.get('received', 0)}"
                             f"  rejected: {state.get('rejected', 0)}")]
    for name, robot in state["robots"].items():
        status = shown(robot.get("status", "UNKNOWN"))
        title = Text(f"robot {shown(name)}  ")
        title.append(status + (" (silent)" if robot.get("stale") else "")
                     + ("" if robot.get("online", True) else " (stopped)"),
                     style=STYLE.get(status, "") if colour else "")
        table = Table(title=title, title_justify="left", expand=False)
        table.add_column("entity", no_wrap=True)
        table.add_column("kind")
        table.add_column("health")
        table.add_column("failures", justify="right")
        for ename, entity in sorted(robot["entities"].items(),
                                    key=lambda kv: (kv[1]["kind"] != "robot", kv[0])):
            health = shown(entity["health"]) if entity["online"] else "UNKNOWN"
            word = health if entity["online"] else f"{health} (offline)"
            if entity["bit"]:
                word += " [BIT]"
            label = "(robot)" if entity["kind"] == "robot" else shown(ename)
            table.add_row(Text(label), Text(shown(entity["kind"])),
                          Text(word, style=STYLE.get(health, "") if colour else ""),
                          str(entity["failures"] or ""))
        parts.append(table)
        events = Table(show_header=False, box=None, padding=(0, 1))
        for event in list(robot["events"])[-8:]:
            stamp = time.strftime("%H:%M:%S", time.localtime(event["time"]))
            origin = " [log]" if event["origin"] == "log" else ""
            events.add_row(stamp, Text(shown(event["kind"])),
                           Text(f"{shown(event['entity'])}: {shown(event['text'])}{origin}"))
        if events.row_count:
            parts.append(events)
    for problem in state.get("problems", [])[:5]:
        parts.append(Text("problem: " + shown(problem), style="red" if colour else ""))
    return Group(*parts)


def _stable(state: dict[str, Any]) -> str:
    """The state without what changes on every sample, to print only real changes."""
    return json.dumps({**state, "received": None}, sort_keys=True, default=str)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    from blackbox.station.follow import StationFollower
    from blackbox.station.store import StationStore

    settings = transport_settings(args)
    if settings is None:
        return 2
    if args.stale_after <= 0:
        print("error: --stale-after must be positive", file=sys.stderr)
        return 2
    store = StationStore(":memory:", stale_after=args.stale_after)
    follower = StationFollower(store, settings, backfill=max(0.0, args.backfill),
                               station_id=f"listen-{os.getpid()}")
    tty = sys.stdout.isatty() and not args.json
    end = None if args.duration is None else time.monotonic() + args.duration
    console = Console(force_terminal=tty, no_color=not tty, width=None if tty else 120)
    last = ""
    follower.start()
    try:
        if tty:
            with Live(render(follower.snapshot()), console=console, auto_refresh=False,
                      transient=False) as live:
                while end is None or time.monotonic() < end:
                    store.wait_for_change(store.sequence, 0.5)
                    live.update(render(follower.snapshot()), refresh=True)
        else:
            while end is None or time.monotonic() < end:
                store.wait_for_change(store.sequence, 0.2)
                state = follower.snapshot()
                text = _stable(state)
                if text == last:
                    continue
                last = text
                if args.json:
                    print(json.dumps(state, sort_keys=True, default=str), flush=True)
                else:
                    console.print(render(state, colour=False))
                    console.print()
                    sys.stdout.flush()
    except KeyboardInterrupt:
        pass
    finally:
        follower.stop()
        store.close()
    return 0
