"""``blackbox station``: the remote station, a web application for a fleet of black boxes.

``blackbox station`` joins the DDS domain (or Zenoh routers, ``--zenoh``), follows every robot
on it into its own database and serves the web pages (http://127.0.0.1:8080 unless
``--bind`` says otherwise; HTTPS with ``--tls-cert``/``--tls-key``). ``blackbox station
user add NAME --role ROLE`` makes an account; there is none until then.
"""

from __future__ import annotations

import argparse
import dataclasses
import getpass
import os
import socket
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from blackbox.cli.router import add_tls_arguments, zenoh_settings
from blackbox.station.auth import Auth, AuthPolicy, Role, StationAuthError

EXIT_USAGE = 2

_DEFAULT_POLICY = AuthPolicy()


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("station", help="the remote station: follow a fleet, serve its web GUI",
                       description="Follow every black box on a DDS domain, keep what they say "
                       "in a database and serve the station's web pages.")
    p.add_argument("--db", default="station.db", metavar="DATABASE",
                   help="the station's database: an SQLite file (default station.db, also "
                        "sqlite:///FILE) or postgresql://USER@HOST:PORT/NAME, which several "
                        "station processes can share (docs/station.md, Fleet deployment)")
    p.add_argument("--bind", default="127.0.0.1:8080", metavar="HOST:PORT",
                   help="address of the web server (default 127.0.0.1:8080; port 0 = any free)")
    p.add_argument("--domain", type=int, default=0, help="DDS domain id (default 0)")
    p.add_argument("--partition", default="blackbox", help="DDS partition (default blackbox)")
    p.add_argument("--zenoh", action="append", default=None, metavar="ENDPOINT",
                   help="follow the robots through this Zenoh router (e.g. "
                        "tcp/router.example:7447; repeatable) instead of DDS "
                        "(docs/station.md, Fleet deployment)")
    add_tls_arguments(p)
    p.add_argument("--stale-after", type=float, default=10.0, metavar="S",
                   help="a robot silent this long is shown UNKNOWN (default 10 s)")
    p.add_argument("--tls-cert", type=Path, default=None, help="serve HTTPS with this certificate")
    p.add_argument("--tls-key", type=Path, default=None, help="... and this private key")
    p.add_argument("--trusted-proxy", action="append", default=[], metavar="ADDRESS",
                   help="a reverse proxy (address or network) whose X-Forwarded-For and "
                        "X-Forwarded-Proto are believed; repeat for more (default: none, "
                        "the audit shows the connecting address)")
    p.add_argument("--key", type=Path, default=None, metavar="FILE",
                   help="this station's private key (blackbox keygen) signing log requests "
                        "and IBIT commands; default $BLACKBOX_STATION_KEY. Robots answer only "
                        "stations their configuration lists (docs/health.md)")
    p.add_argument("--alerts", type=Path, default=None, metavar="FILE",
                   help="alert rules and channels (YAML; docs/station.md \"Alerts\")")
    p.add_argument("--metrics-token-env", default=None, metavar="NAME",
                   help="/metrics answers only 'Authorization: Bearer <token>' with the token "
                        "in environment variable NAME (default: /metrics is open)")
    p.add_argument("--robots", type=Path, default=None, metavar="FILE",
                   help="enrol the robots of FILE at start: lines 'ed25519 <base64> ROBOT_ID' "
                        "(their keygen .pub files); their health is then authenticated")
    p.add_argument("--login-backoff", type=float, default=_DEFAULT_POLICY.base_backoff, metavar="S",
                   help="after 3 failed log-ins of a user name from one address, the next "
                        "waits S seconds, each further failure twice as long (default "
                        f"{_DEFAULT_POLICY.base_backoff:g} s, at most 5 min)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--ready-file", type=Path, default=None, metavar="FILE",
                   help="write the URL here once serving (for scripts and tests)")
    p.set_defaults(func=serve_command)

    users = p.add_subparsers(dest="station_command", metavar="COMMAND")
    user = users.add_parser("user", help="manage the station's accounts")
    actions = user.add_subparsers(dest="user_command", metavar="ACTION")
    add = actions.add_parser("add", help="add an account (password read without echo, or "
                             "from stdin when it is not a terminal)")
    add.add_argument("name")
    add.add_argument("--role", required=True, choices=["viewer", "operator", "admin"])
    add.add_argument("--db", dest="user_db", default=None,
                     help="the station database (default: the station's --db)")
    add.set_defaults(func=user_add_command)
    passwd = actions.add_parser("passwd", help="set a new password (ends the user's sessions)")
    passwd.add_argument("name")
    passwd.add_argument("--db", dest="user_db", default=None)
    passwd.set_defaults(func=user_passwd_command)
    listing = actions.add_parser("list", help="list the accounts")
    listing.add_argument("--db", dest="user_db", default=None)
    listing.set_defaults(func=user_list_command)
    remove = actions.add_parser("remove", help="remove an account")
    remove.add_argument("name")
    remove.add_argument("--db", dest="user_db", default=None)
    remove.set_defaults(func=user_remove_command)

    robots = users.add_parser("robots", help="the robots this station trusts (their keys)")
    robot_actions = robots.add_subparsers(dest="robots_command", metavar="ACTION")
    enrol = robot_actions.add_parser(
        "enrol", help="trust a robot's key: --key ROBOT.key.pub, or --seen to confirm the "
                      "one key the station saw its signatures carry (trust on first use)")
    enrol.add_argument("robot")
    how = enrol.add_mutually_exclusive_group(required=True)
    how.add_argument("--key", dest="robot_key", type=Path, metavar="FILE.pub")
    how.add_argument("--seen", action="store_true")
    enrol.add_argument("--db", dest="user_db", default=None)
    enrol.set_defaults(func=robots_enrol_command)
    rlist = robot_actions.add_parser("list", help="trusted robots, then keys seen but not "
                                                  "trusted")
    rlist.add_argument("--db", dest="user_db", default=None)
    rlist.set_defaults(func=robots_list_command)
    rremove = robot_actions.add_parser("remove", help="stop trusting a robot's key")
    rremove.add_argument("robot")
    rremove.add_argument("--db", dest="user_db", default=None)
    rremove.set_defaults(func=robots_remove_command)


def open_databases(path: str | Path, stale_after: float = 10.0,
                   policy: AuthPolicy | None = None) -> tuple[Any, Auth]:
    """The station store, then the accounts in the same database (the store must create
    it: it refuses a file that already has other tables)."""
    from blackbox.station.store import StationStore

    store = StationStore.open(path, stale_after=stale_after)
    return store, Auth(store.database, policy)


def read_password(name: str) -> str:
    if sys.stdin.isatty():
        first = getpass.getpass(f"password for {name}: ")
        second = getpass.getpass("again: ")
        if first != second:
            raise StationAuthError("the two passwords differ")
        return first
    return sys.stdin.readline().rstrip("\r\n")


def _db(args: argparse.Namespace) -> str:
    return str(args.user_db or args.db)


def _usage_error(message: object) -> int:
    print(f"error: {message}", file=sys.stderr)
    return EXIT_USAGE


def _open_or_say(path: str | Path, stale_after: float = 10.0,
                 policy: AuthPolicy | None = None) -> tuple[Any, Auth] | None:
    """:func:`open_databases`, or ``None`` after saying why the file cannot be opened."""
    from blackbox.station.store import StationStoreError

    try:
        return open_databases(path, stale_after, policy)
    except StationStoreError as exc:
        _usage_error(exc)
        return None


def _with_accounts(args: argparse.Namespace, action: Callable[[Auth], object]) -> int:
    """Run one ``station user`` action on the accounts; a refused one exits 2."""
    opened = _open_or_say(_db(args))
    if opened is None:
        return EXIT_USAGE
    store, auth = opened
    try:
        action(auth)
    except StationAuthError as exc:
        return _usage_error(exc)
    finally:
        auth.close()
        store.close()
    return 0


def user_add_command(args: argparse.Namespace) -> int:
    code = _with_accounts(args, lambda auth: auth.add_user(
        args.name, read_password(args.name), Role.parse(args.role)))
    if code == 0:
        from blackbox.station.database import open_database

        print(f"station: user {args.name} ({args.role}) added to "
              f"{open_database(_db(args)).describe()}", file=sys.stderr)
    return code


def user_passwd_command(args: argparse.Namespace) -> int:
    return _with_accounts(args, lambda auth: auth.set_password(
        args.name, read_password(args.name), by="cli", address="local"))


def _print_users(auth: Auth) -> None:
    for user in auth.users():
        print(f"{user.name}\t{user.role.label}")


def user_list_command(args: argparse.Namespace) -> int:
    return _with_accounts(args, _print_users)


def user_remove_command(args: argparse.Namespace) -> int:
    return _with_accounts(args, lambda auth: auth.remove_user(args.name, by="cli",
                                                               address="local"))


def _with_robot_keys(args: argparse.Namespace, action: Callable[[Any], int]) -> int:
    """Run one ``station robots`` action on the station database's trusted robots."""
    from blackbox.station.enrolment import EnrolmentError, RobotKeys

    opened = _open_or_say(_db(args))
    if opened is None:
        return EXIT_USAGE
    store, auth = opened
    auth.close()
    try:
        keys = RobotKeys(store.database)
        try:
            return action(keys)
        finally:
            keys.close()
    except EnrolmentError as exc:
        return _usage_error(exc)
    finally:
        store.close()


def robots_enrol_command(args: argparse.Namespace) -> int:
    from blackbox.station.enrolment import read_public_key_file

    def enrol(keys: Any) -> int:
        if args.seen:
            robot = keys.confirm_seen(args.robot)
        else:
            robot = keys.enrol(args.robot, read_public_key_file(args.robot_key))
        print(f"station: robot {robot.robot_id} enrolled with key {robot.public_key} "
              f"({robot.source})", file=sys.stderr)
        return 0
    return _with_robot_keys(args, enrol)


def robots_list_command(args: argparse.Namespace) -> int:
    def show(keys: Any) -> int:
        trusted = {r.robot_id: r.public_key for r in keys.robots()}
        for robot, key in trusted.items():
            print(f"{robot}\ttrusted\t{key}")
        for seen in keys.seen():
            if trusted.get(seen.robot_id) != seen.public_key:
                print(f"{seen.robot_id}\tseen\t{seen.public_key}")
        return 0
    return _with_robot_keys(args, show)


def robots_remove_command(args: argparse.Namespace) -> int:
    def remove(keys: Any) -> int:
        if not keys.remove(args.robot):
            return _usage_error(f"robot {args.robot!r} is not enrolled")
        return 0
    return _with_robot_keys(args, remove)


def parse_bind(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or int(port) > 65535:
        raise ValueError(f"--bind wants HOST:PORT, got {text!r}")
    return host.strip("[]") or "127.0.0.1", int(port)


def serve_command(args: argparse.Namespace) -> int:
    if getattr(args, "station_command", None) == "user" and not getattr(args, "user_command",
                                                                          None):
        print("usage: blackbox station user {add,passwd,list,remove} ...", file=sys.stderr)
        return EXIT_USAGE
    if getattr(args, "station_command", None) == "robots" and not getattr(
            args, "robots_command", None):
        print("usage: blackbox station robots {enrol,list,remove} ...", file=sys.stderr)
        return EXIT_USAGE
    if (args.tls_cert is None) != (args.tls_key is None):
        return _usage_error("--tls-cert and --tls-key go together")
    try:
        host, port = parse_bind(args.bind)
    except ValueError as exc:
        return _usage_error(exc)
    from blackbox.station.alerts.rules import AlertConfig, load_alert_config

    if args.metrics_token_env and len(os.environ.get(args.metrics_token_env, "")) < 16:
        return _usage_error(f"--metrics-token-env: ${args.metrics_token_env} must hold a "
                            "token of at least 16 characters")

    alerts = load_alert_config(args.alerts) if args.alerts is not None \
        else AlertConfig("<none>")  # a ConfigError here exits 2 naming file, line, key
    if not 0 < args.login_backoff <= _DEFAULT_POLICY.max_backoff:
        return _usage_error(f"--login-backoff: {args.login_backoff:g} s is not within "
                            f"0 < S <= {_DEFAULT_POLICY.max_backoff:g}")
    policy = AuthPolicy(base_backoff=args.login_backoff)
    opened = _open_or_say(args.db, args.stale_after, policy)
    if opened is None:
        return EXIT_USAGE
    store, auth = opened
    try:
        return serve(args, store, auth, host, port, alerts)
    finally:
        auth.close()
        store.close()


def serve(args: argparse.Namespace, store: Any, auth: Auth, host: str, port: int,
          alert_config: Any = None) -> int:
    import uvicorn

    from blackbox.station.alerts.rules import AlertConfig
    from blackbox.station.alerts.service import AlertService
    from blackbox.station.database import without_password
    from blackbox.station.enrolment import EnrolmentError, RobotKeys, read_robots_file
    from blackbox.station.follow import StationFollower
    from blackbox.station.store import WRITER_SWITCH_INTERVAL
    from blackbox.station.web.app import WebSettings, create_app
    from blackbox.station.web.limits import uvicorn_options
    from blackbox.transport.participant import TransportSettings

    if not auth.users():
        print(f"station: no account yet; add one with: blackbox station user add NAME "
              f"--role admin --db {without_password(str(args.db))}", file=sys.stderr)
    from blackbox.transport.auth import RequestAuthError, RequestSigner

    try:
        signer = (RequestSigner.from_file(args.key) if args.key is not None
                  else RequestSigner.from_environment())
    except (RequestAuthError, OSError) as exc:
        return _usage_error(f"--key: {exc}")
    if signer is None:
        print("station: no station key (--key or $BLACKBOX_STATION_KEY): robots will refuse "
              "its log requests and IBIT commands", file=sys.stderr)
    try:
        robot_keys = RobotKeys(store.database)
        for robot_id, key in read_robots_file(args.robots) if args.robots else []:
            robot_keys.enrol(robot_id, key, "file")
    except EnrolmentError as exc:
        return _usage_error(f"--robots: {exc}")
    if not robot_keys.robots():
        print("station: no robot enrolled (--robots or blackbox station robots enrol): "
              "robot health is shown unauthenticated", file=sys.stderr)
    zenoh = zenoh_settings(args)
    if zenoh is not None:
        zenoh = dataclasses.replace(zenoh, partition=args.partition)
    follower = StationFollower(store, TransportSettings(args.domain, args.partition,
                                                        zenoh=zenoh),
                               signer=signer, robot_keys=robot_keys)
    sys.setswitchinterval(min(sys.getswitchinterval(), WRITER_SWITCH_INTERVAL))
    follower.start()
    alerts = AlertService(store, store.database, alert_config or AlertConfig("<none>"),
                          audit=lambda u, a, t, o, d: auth.audit(u, a, t, o, "station", d))
    alerts.start()
    stop = threading.Event()
    tls = args.tls_cert is not None
    app = create_app(auth, store, follower, WebSettings(secure_cookies=tls), stop=stop,
                     alerts=alerts, metrics_token=os.environ.get(args.metrics_token_env)
                     if args.metrics_token_env else None)
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen(2048)  # connections wait in the backlog from here on: "ready" is true
    except OSError as exc:
        follower.stop()
        alerts.stop()
        return _usage_error(f"cannot listen on {host}:{port}: {exc.strerror}")
    config = uvicorn.Config(app, log_level="warning", access_log=False,
                            ssl_certfile=str(args.tls_cert) if tls else None,
                            ssl_keyfile=str(args.tls_key) if tls else None,
                            timeout_graceful_shutdown=3,
                            **uvicorn_options(args.trusted_proxy))
    server = uvicorn.Server(config)
    bound = sock.getsockname()
    url = f"{'https' if tls else 'http'}://{host if ':' not in host else f'[{host}]'}:{bound[1]}/"
    bus = f"Zenoh via {', '.join(args.zenoh)}" if zenoh else f"DDS domain {args.domain}"
    print(f"station: serving {url} ({bus}, database {store.path})",
          file=sys.stderr)
    if args.ready_file is not None:
        # Whole or not at all: a script that sees the file reads the URL, never an empty one.
        partial = args.ready_file.with_name(args.ready_file.name + ".partial")
        partial.write_text(url + "\n")
        os.replace(partial, args.ready_file)
    timer = None
    if args.duration is not None:
        def finish() -> None:
            stop.set()
            server.should_exit = True
        timer = threading.Timer(args.duration, finish)
        timer.daemon = True
        timer.start()
    original = server.handle_exit

    def on_signal(sig: int, frame: Any) -> None:
        stop.set()  # ends the live streams, else uvicorn waits for them
        original(sig, frame)

    server.handle_exit = on_signal  # type: ignore[method-assign]
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:  # uvicorn re-raises the Ctrl-C it handled; a clean stop
        pass
    finally:
        stop.set()
        if timer is not None:
            timer.cancel()
        follower.stop()
        alerts.stop()
    return 0
