"""``blackbox keygen``: a key pair for a station (signed log requests and built-in tests) or
a robot (signed health: every sample, log reply and IBIT result)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("keygen", help="create a station's or a robot's signing key pair",
                       description="Create an Ed25519 key pair. A station's private key "
                                   "(FILE, readable by you only) signs `request-logs --key` "
                                   "and built-in test requests; its public key (FILE.pub) goes "
                                   "into the robot's transport.access list. A robot's key "
                                   "(--robot, named by the robot id) signs its health "
                                   "(`blackbox run --key FILE`); stations enrol FILE.pub "
                                   "(`blackbox station robots enrol`). See docs/health.md.")
    p.add_argument("file", type=Path, metavar="FILE", help="where to write the private key")
    p.add_argument("--name", default=None,
                   help="the station's name in the robot's access list (default: FILE's stem)")
    p.add_argument("--robot", default=None, metavar="ROBOT_ID",
                   help="a robot's key: named by its robot id")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from blackbox.transport.auth import generate_key_pair

    name = args.robot or args.name or args.file.stem
    public = generate_key_pair(args.file, name)  # a refusal is a BlackBoxError: exit 2
    key = public.read_text().split()[1]
    if args.robot:
        print(f"robot key {args.file} (private, mode 0600) and {public} (public)\n"
              f"sign the robot's health with: blackbox run --key {args.file} ...\n"
              f"trust it on a station with: blackbox station robots enrol {args.robot} "
              f"--key {public}")
        return 0
    print(f"station key {args.file} (private, mode 0600) and {public} (public)\n"
          "allow it on a robot with, in the robot's configuration:\n"
          "  transport:\n    access:\n      stations:\n"
          f"        - {{name: {name}, public_key: \"{key}\", may: [logs, ibit]}}")
    return 0
