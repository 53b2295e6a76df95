"""``blackbox request-logs``: fetch a robot's recorded health log over DDS."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from blackbox.cli.listen import add_bus_arguments, open_bus
from blackbox.timestamps import parse_timestamp


def _time(text: str) -> float:
    """UTC unless the text says otherwise, as ``blackbox log`` and the station read it."""
    try:
        return parse_timestamp(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected seconds since the epoch or an ISO date-time, got {text!r}") from None


def max_entries(text: str) -> int:
    from blackbox.transport.logservice import MAX_ENTRIES

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 0 <= value <= MAX_ENTRIES:
        raise argparse.ArgumentTypeError(f"must be 0 (all) or 1..{MAX_ENTRIES}, got {value}")
    return value


def register(sub: Any) -> None:
    p = sub.add_parser("request-logs", help="fetch a robot's health log over DDS",
                       description=__doc__)
    add_bus_arguments(p)
    p.add_argument("--robot", required=True, help="robot id (as in its configuration)")
    p.add_argument("--entity", help="node or topic (exact, or a glob with * ? [)")
    p.add_argument("--characteristic", help="observer type (exact or glob)")
    p.add_argument("--since", type=_time,
                   help="start time (epoch seconds or ISO date-time, UTC unless it says)")
    p.add_argument("--until", type=_time, help="end time (epoch seconds or ISO date-time)")
    p.add_argument("--kind", action="append", default=[], dest="kinds",
                   help="entry kind (repeatable): observation, exceedance, diagnosis, "
                        "failure, sample, blackbox_event, config, snapshot")
    p.add_argument("--max", type=max_entries, default=0, dest="max_entries",
                   help="at most this many entries, 1..1000000 (default 0: all, at most "
                        "1000000)")
    p.add_argument("--key", type=Path, default=None, metavar="FILE",
                   help="sign the request with this station key (blackbox keygen; default: "
                        "$BLACKBOX_STATION_KEY); robots answer only stations they list")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait (default 10)")
    p.add_argument("--out", help="write JSON lines here instead of standard output")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from blackbox.transport.auth import RequestSigner
    from blackbox.transport.logservice import LogClient

    # a key that cannot be used raises RequestAuthError, a BlackBoxError: main says why, exit 2
    signer = RequestSigner.from_file(args.key) if args.key else RequestSigner.from_environment()
    bus = open_bus(args)
    if bus is None:
        return 2
    try:
        client = LogClient(bus, signer=signer)
        answer = client.request(args.robot, entity=args.entity,
                                characteristic=args.characteristic, since=args.since,
                                until=args.until, kinds=args.kinds,
                                max_entries=args.max_entries, timeout=args.timeout)
    finally:
        bus.close()
    if answer.status != "ok":
        print(f"error: robot {args.robot}: {answer.status}", file=sys.stderr)
        return 1
    lines = "".join(json.dumps(e, sort_keys=True) + "\n" for e in answer.entries)
    if args.out:
        try:
            with open(args.out, "w", encoding="utf-8") as f:
                f.write(lines)
        except OSError as exc:
            print(f"error: cannot write {args.out}: {exc}", file=sys.stderr)
            return 1
    else:
        sys.stdout.write(lines)
    print(f"{len(answer.entries)} entries in {answer.chunks} chunks from {args.robot}",
          file=sys.stderr)
    return 0
