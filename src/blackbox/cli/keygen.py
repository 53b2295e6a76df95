"""``blackbox keygen``: a station's key pair for signed log requests and built-in tests."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("keygen", help="create a station key pair for signed remote requests",
                       description="Create an Ed25519 key pair for a station. The private key "
                                   "(FILE, readable by you only) signs `request-logs --key` "
                                   "and built-in test requests; the public key (FILE.pub) goes "
                                   "into the robot's transport.access list (docs/health.md).")
    p.add_argument("file", type=Path, metavar="FILE", help="where to write the private key")
    p.add_argument("--name", default=None,
                   help="the station's name in the robot's access list (default: FILE's stem)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from blackbox.transport.auth import generate_key_pair

    name = args.name or args.file.stem
    public = generate_key_pair(args.file, name)  # a refusal is a BlackBoxError: exit 2
    key = public.read_text().split()[1]
    print(f"station key {args.file} (private, mode 0600) and {public} (public)\n"
          "allow it on a robot with, in the robot's configuration:\n"
          "  transport:\n    access:\n      stations:\n"
          f"        - {{name: {name}, public_key: \"{key}\", may: [logs, ibit]}}")
    return 0
