"""CPU per message of the TCPROS receive path alone: native loop against the Python one.

    .venv/bin/python benchmarks/ros1_native.py [--rate 5000] [--seconds 5] [--repeat 3]
        [--variants python,native,native:0.005,before] [--before SRC] [--callgrind]

A sender process writes one Float64 frame per ``send`` (as rospy does) at ``--rate`` to a
TCP connection on 127.0.0.1; a reader process runs one ``TcprosReader`` in compact mode (the
way the black box reads a rate-only topic) and counts what it is handed. The reader's own
CPU (user + system, ``getrusage``) over the window, divided by the messages it got, is the
figure; the sender is not counted. Variants: ``python`` (``BLACKBOX_PURE_PYTHON=1``),
``native`` (the compiled loop, the reader's default hand-over), ``native:S`` (hand-over
every S seconds), ``before`` (the native reader of ``--before SRC``, another checkout's
``src/`` with its ``_tcpros`` built in place). Variants alternate within each repeat, so
they share the machine's load, which is printed with every row: the machine is shared, so
read the rows of one repeat side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FRAME = struct.pack("<I", 8) + struct.pack("<d", 1.0)


def _cpu() -> tuple[float, float]:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime, r.ru_stime


def _switches() -> tuple[int, int]:
    """Voluntary and involuntary context switches of the whole process: a voluntary one is
    a thread going to sleep, so per message it says how many wake-ups a message costs."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_nvcsw, r.ru_nivcsw


def reader(port: int, seconds: float, warmup: float, hand_over: float | None) -> None:
    from blackbox.events import ArrivalBatch
    from blackbox.sources.ros1.decoder import MessageDecoder
    from blackbox.sources.ros1.stream_reader import Arrivals, StreamKey, TcprosReader

    # The consumer only keeps what it is handed (one list extend per hand-over) and counts
    # it after the window, so the figure is the receive path's alone: what the pipeline then
    # does with each batch is measured with the whole black box (ros1_scaling.py).
    kept: list[Arrivals] = []
    handovers = [0]

    def on_batch(batch: Arrivals) -> None:
        kept.append(batch)
        handovers[0] += 1

    kwargs = {} if hand_over is None else {"hand_over": hand_over}
    r = TcprosReader(print, print, lambda key: None, MessageDecoder(), on_batch=on_batch,
                     compact=True, **kwargs)
    r.start()
    sock = socket.create_connection(("127.0.0.1", port))
    r.add(StreamKey("/t", "/pub"), sock, 1 << 20, None)
    time.sleep(warmup)
    r.flush()
    first, h0 = len(kept), handovers[0]
    c0, s0, w0 = _cpu(), _switches(), time.monotonic()
    time.sleep(seconds)
    r.flush()  # what arrived in the window is handed on, inside it
    c1, s1, w1 = _cpu(), _switches(), time.monotonic()
    last, h1 = len(kept), handovers[0]
    native = r.native
    r.close()
    window = [item for batch in kept[first:last] for item in batch]
    got = {"messages": sum(i.count if type(i) is ArrivalBatch else 1 for i in window),
           "records": len(window), "handovers": h1 - h0,
           "switches": s1[0] - s0[0], "involuntary": s1[1] - s0[1]}
    user, system = c1[0] - c0[0], c1[1] - c0[1]
    print(json.dumps({"native": native, "cpu": user + system, "user": user, "system": system,
                      "wall": w1 - w0, **got}))


def run(variant: str, rate: float, seconds: float, warmup: float,
        callgrind: Path | None = None, before: Path | None = None) -> dict[str, object]:
    env = dict(os.environ)
    hand_over: float | None = None
    if variant == "before":  # the default native reader of another src/ (built in place)
        if before is None:
            raise SystemExit("variant 'before' needs --before SRC")
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(before),
                                                          env.get("PYTHONPATH", "")]))
        env.pop("BLACKBOX_PURE_PYTHON", None)
    elif variant == "python":
        env["BLACKBOX_PURE_PYTHON"] = "1"
    else:
        env.pop("BLACKBOX_PURE_PYTHON", None)
        if ":" in variant:
            hand_over = float(variant.split(":", 1)[1])
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    tool = [] if callgrind is None else [
        "valgrind", "--tool=callgrind", f"--callgrind-out-file={callgrind}", "--dump-instr=no"]
    proc = subprocess.Popen([*tool, sys.executable, __file__, "--reader", str(port),
                             str(seconds), str(warmup), repr(hand_over)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            cwd=ROOT)
    conn, _ = server.accept()
    server.close()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    period = 1.0 / rate
    due = time.monotonic()
    try:
        while proc.poll() is None:  # until the reader has measured and gone
            now = time.monotonic()
            while due <= now:  # one message per write, as rospy writes them
                conn.send(FRAME)
                due += period
            time.sleep(max(0.0, due - time.monotonic()))
    except OSError:
        pass
    out, _ = proc.communicate(timeout=30)
    conn.close()
    row: dict[str, object] = json.loads(out.strip().splitlines()[-1])
    if callgrind is not None:
        totals = [line for line in callgrind.read_text().splitlines()
                  if line.startswith(("summary:", "totals:"))]
        row["instructions"] = int(totals[-1].split()[1])
    msgs = int(row["messages"])  # type: ignore[call-overload]
    row.update(variant=variant, rate=rate, load=os.getloadavg()[0],
               us_per_msg=1e6 * float(row["cpu"]) / max(1, msgs),  # type: ignore[arg-type]
               msgs_per_record=msgs / max(1, int(row["records"])))  # type: ignore[call-overload]
    return row


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args and args[0] == "--reader":
        port, seconds, warmup, hand = args[1:5]
        reader(int(port), float(seconds), float(warmup), None if hand == "None" else float(hand))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=5000.0)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--warmup", type=float, default=1.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--variants", default="python,native")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--before", type=Path, metavar="SRC",
                        help="a src/ directory (its _tcpros built in place) that the variant "
                             "'before' runs, for a before/after comparison in one run")
    parser.add_argument("--callgrind", action="store_true",
                        help="count the reader's user-space instructions per message under "
                             "valgrind instead (load-independent): two runs per variant, "
                             "SECONDS and 3 x SECONDS long, differenced")
    a = parser.parse_args(args)
    if a.callgrind:
        return _callgrind(a.variants.split(","), a.rate, a.seconds, a.warmup, a.before)
    rows = []
    print(f"{'variant':>14} {'native':>6} {'msg/s':>8} {'us/msg':>7} {'user':>5} {'sys':>5} "
          f"{'msg/recv':>8} {'hand-overs/s':>12} {'sleeps/msg':>10} {'load':>5}")
    for _ in range(a.repeat):
        for variant in a.variants.split(","):
            row = run(variant, a.rate, a.seconds, a.warmup, before=a.before)
            rows.append(row)
            wall = float(row["wall"])  # type: ignore[arg-type]
            print(f"{variant:>14} {row['native']!s:>6} {int(row['messages']) / wall:8.0f} "  # type: ignore[call-overload]
                  f"{row['us_per_msg']:7.2f} "
                  f"{1e6 * float(row['user']) / max(1, int(row['messages'])):5.1f} "  # type: ignore[arg-type, call-overload]
                  f"{1e6 * float(row['system']) / max(1, int(row['messages'])):5.1f} "  # type: ignore[arg-type, call-overload]
                  f"{row['msgs_per_record']:8.2f} "
                  f"{int(row['handovers']) / wall:12.0f} "  # type: ignore[call-overload]
                  f"{int(row['switches']) / max(1, int(row['messages'])):10.2f} "  # type: ignore[call-overload]
                  f"{row['load']:5.2f}", flush=True)
    if a.json:
        a.json.write_text(json.dumps(rows, indent=2))
    return 0


def _callgrind(variants: list[str], rate: float, seconds: float, warmup: float,
               before: Path | None) -> int:
    """Instructions per message = the difference of two runs' totals over the difference
    of their messages: start-up and imports cancel out."""
    import tempfile

    print(f"{'variant':>14} {'instructions/msg':>16} {'msg/recv':>8} {'messages':>9} {'load':>5}")
    with tempfile.TemporaryDirectory(prefix="ros1-native-cg-") as tmp:
        for variant in variants:
            short = run(variant, rate, seconds, warmup, Path(tmp) / f"{variant}-1.out", before)
            long = run(variant, rate, 3 * seconds, warmup, Path(tmp) / f"{variant}-3.out",
                       before)
            dm = int(long["messages"]) - int(short["messages"])  # type: ignore[call-overload]
            di = int(long["instructions"]) - int(short["instructions"])  # type: ignore[call-overload]
            print(f"{variant:>14} {di / max(1, dm):16.0f} {long['msgs_per_record']:8.2f} "
                  f"{dm:9d} {os.getloadavg()[0]:5.2f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
