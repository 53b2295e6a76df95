"""``blackbox router``: a Zenoh router that robots and stations at different sites reach
(``blackbox run --zenoh`` / ``blackbox station --zenoh``), see docs/station.md."""

from __future__ import annotations

import argparse
import signal
import threading
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from blackbox.transport.zenoh_bus import ZenohSettings


def register(sub: Any) -> None:
    p = sub.add_parser("router", help="run a Zenoh router for robots and stations across "
                                      "networks",
                       description="Run a Zenoh router in this process. Robots "
                                   "(`blackbox run --zenoh ENDPOINT`) and stations "
                                   "(`blackbox station --zenoh ENDPOINT`) connect to it; "
                                   "routers at several sites connect to each other with "
                                   "--connect. See docs/station.md, Fleet deployment.")
    p.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help="where to listen, e.g. tcp/0.0.0.0:7447 or tls/0.0.0.0:7447 "
                        "(repeatable; default tcp/127.0.0.1:7447)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="another router to join (repeatable)")
    add_tls_arguments(p)
    p.set_defaults(func=run)


def add_tls_arguments(p: argparse.ArgumentParser) -> None:
    """``--zenoh-ca``, ``--zenoh-certificate``, ``--zenoh-key``: Zenoh TLS files, shared by
    router, run and station (the station's ``--tls-*`` are its HTTPS)."""
    p.add_argument("--zenoh-ca", default=None, metavar="PEM",
                   help="the CA certificate that signed the routers' certificates")
    p.add_argument("--zenoh-certificate", default=None, metavar="PEM",
                   help="this side's certificate for Zenoh TLS (a router's tls/ listener "
                        "needs one)")
    p.add_argument("--zenoh-key", default=None, metavar="PEM",
                   help="the private key of --zenoh-certificate")


def zenoh_settings(args: argparse.Namespace) -> ZenohSettings | None:
    """``--zenoh`` and the TLS files as settings; a bad endpoint is a one-line error."""
    if not args.zenoh:
        return None
    from blackbox.errors import BlackBoxError
    from blackbox.transport.zenoh_bus import ZenohSettings

    try:
        return ZenohSettings(tuple(args.zenoh), root_ca=args.zenoh_ca,
                             certificate=args.zenoh_certificate,
                             private_key=args.zenoh_key)
    except ValueError as exc:
        raise BlackBoxError(f"--zenoh: {exc}") from None


def run(args: argparse.Namespace) -> int:
    from blackbox.errors import BlackBoxError
    from blackbox.transport.zenoh_router import RouterSettings, open_router

    try:
        settings = RouterSettings(tuple(args.listen or ("tcp/127.0.0.1:7447",)),
                                  tuple(args.connect), args.zenoh_ca, args.zenoh_certificate,
                                  args.zenoh_key)
    except ValueError as exc:
        raise BlackBoxError(str(exc)) from None
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    router = open_router(settings)
    print(f"router: listening on {', '.join(settings.listen)}", flush=True)
    try:
        stop.wait()
    finally:
        router.close()
    return 0
