"""Bag replay throughput: messages/s and MB/s of ``--source bag:FILE`` on a simulated clock.

Writes, in a temporary directory that is deleted afterwards:

* an image bag of at least 1 GB (ROS 1, ``sensor_msgs/Image`` 640x480 rgb8 at 15 Hz,
  written with rosbags' writer, uncompressed chunks as ``rosbag record`` writes them);
* a small-message bag (``std_msgs/Float64`` on 10 topics) in three formats: ROS 1 bag,
  MCAP (ROS 1 encoding, zstd chunks, as the recorder writes snapshots) and rosbag2 sqlite3.

Then replays each: the bag source alone with timing only (what ``hz``/``timeout`` need),
the source decoding every value, the whole black box (``blackbox.app.build``, hz + timeout
observers, simulated clock, no output files), and side by side rosbags' own indexed
``rosbag1.Reader`` reading the same messages without decoding. The files were just written,
so they are read from the page cache: figures are CPU-bound replay rates, not disk rates.

Run: .venv/bin/python benchmarks/bag_replay.py [--gb 1.05] [--small 300000] [--dir /tmp]
"""

from __future__ import annotations

import argparse
import platform
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Reader as Ros1Reader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

from blackbox.app import RunOptions, build
from blackbox.events import Interest, MessageArrival, TopicSchema
from blackbox.record.snapshot import Held, write_mcap
from blackbox.sources.bag import BagSource

T0 = 1_700_000_000
IMAGE_BYTES = 640 * 480 * 3


def write_image_bag(path: Path, min_bytes: int) -> int:
    store = get_typestore(Stores.ROS1_NOETIC)
    image_t = store.types["sensor_msgs/msg/Image"]
    header_t = store.types["std_msgs/msg/Header"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    pixels = np.random.default_rng(1).integers(0, 255, IMAGE_BYTES, dtype=np.uint8)
    count = 0
    with Ros1Writer(path) as writer:
        conn = writer.add_connection("/camera/image_raw", "sensor_msgs/msg/Image",
                                     typestore=store, callerid="/camera")
        written = 0
        while written < min_bytes:
            stamp = T0 * 10**9 + count * 66_666_667
            msg = image_t(header=header_t(seq=count, stamp=time_t(sec=stamp // 10**9,
                                                                  nanosec=stamp % 10**9),
                                          frame_id="camera"),
                          height=480, width=640, encoding="rgb8", is_bigendian=0,
                          step=640 * 3, data=pixels)
            data = store.serialize_ros1(msg, "sensor_msgs/msg/Image")
            writer.write(conn, stamp, data)
            written += len(data)
            count += 1
    return count


def small_messages(n: int) -> list[tuple[str, int, float]]:
    topics = [f"/bench/value_{i}" for i in range(10)]
    return [(topics[k % 10], T0 * 10**9 + k * 100_000, 15.0 + (k % 7) * 0.1) for k in range(n)]


def write_small(root: Path, n: int) -> dict[str, Path]:
    msgs = small_messages(n)
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    ros2 = get_typestore(Stores.LATEST)
    f1 = ros1.types["std_msgs/msg/Float64"]
    f2 = ros2.types["std_msgs/msg/Float64"]
    paths = {"ROS 1 bag": root / "small.bag", "MCAP (ros1, zstd)": root / "small.mcap",
             "rosbag2 sqlite3": root / "small_rosbag2"}
    with Ros1Writer(paths["ROS 1 bag"]) as writer:
        conns = {t: writer.add_connection(t, "std_msgs/msg/Float64", typestore=ros1,
                                          callerid="/bench") for t in {m[0] for m in msgs}}
        for topic, stamp, value in msgs:
            writer.write(conns[topic], stamp,
                         ros1.serialize_ros1(f1(data=value), "std_msgs/msg/Float64"))
    definition, md5 = ros1.generate_msgdef("std_msgs/msg/Float64", ros_version=1)
    schemas: dict[str, TopicSchema | None] = {
        t: TopicSchema(t, "std_msgs/Float64", "ros1", definition, md5) for t in conns}
    write_mcap([Held(s / 1e9, t, "/bench",
                     ros1.serialize_ros1(f1(data=v), "std_msgs/msg/Float64"))
                for t, s, v in msgs], schemas, paths["MCAP (ros1, zstd)"])
    with Ros2Writer(paths["rosbag2 sqlite3"], version=9,
                    storage_plugin=StoragePlugin.SQLITE3) as writer2:
        conns2 = {t: writer2.add_connection(t, "std_msgs/msg/Float64", typestore=ros2)
                  for t in conns}
        for topic, stamp, value in msgs:
            writer2.write(conns2[topic], stamp,
                          ros2.serialize_cdr(f2(data=value), "std_msgs/msg/Float64"))
    return paths


def size_of(path: Path) -> int:
    if path.is_dir():
        return sum(f.stat().st_size for f in path.iterdir())
    return path.stat().st_size


def timed(fn: Callable[[], int]) -> tuple[int, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    n = fn()
    return n, time.perf_counter() - wall, time.process_time() - cpu


def source_only(path: Path, decode: bool) -> int:
    source = BagSource(path)
    topics = frozenset({"/camera/image_raw"} | {f"/bench/value_{i}" for i in range(10)})
    source.start(Interest(topics=topics, decoded=topics if decode else frozenset()))
    n = 0
    t = source.now()
    while not source.exhausted():
        t += 1.0
        for e in source.poll(t):
            if type(e) is MessageArrival:
                n += 1
                if decode:
                    assert e.value is not None
    return n


def rosbags_reader(path: Path) -> int:
    n = 0
    with Ros1Reader(path) as reader:
        for _conn, _stamp, _data in reader.messages():
            n += 1
    return n


def whole_black_box(path: Path, config: Path) -> int:
    box = build(RunOptions(config=config, source=f"bag:{path}", simulated_clock=True,
                           live=False))
    return box.run().messages


def config_for(topics: list[str], period: float, root: Path) -> Path:
    lines = ["version: 1", "robot: {id: bench}", "observers:"]
    for t in topics:
        lines += [f"  - {{type: hz, topic: {t}, filter: {{type: mean, window_size: 50}},",
                  f"     states: [{{number: 1, name: ok, period: {{value: {{type: gauss, "
                  f"mean: {period}, std_deviation: 0.01}}}}}}]}}",
                  f"  - {{type: timeout, topic: {t}, timeout: 1.0}}"]
    lines += ["diagnosis: {enabled: false}"]
    path = root / f"config_{len(topics)}.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def report(label: str, what: str, n: int, nbytes: int, wall: float, cpu: float) -> None:
    print(f"| {label} | {what} | {n:,} | {wall:.2f} | {cpu:.2f} | {n / wall:,.0f} | "
          f"{nbytes / 1e6 / wall:,.0f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gb", type=float, default=1.05, help="size of the image bag")
    parser.add_argument("--small", type=int, default=300_000, help="small messages")
    parser.add_argument("--dir", type=Path, default=None, help="where the temp dir goes")
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="bag-replay-", dir=args.dir))
    try:
        print(f"machine: {platform.machine()}, {platform.python_implementation()} "
              f"{platform.python_version()}, {platform.platform()}")
        t = time.perf_counter()
        images = write_image_bag(root / "images.bag", int(args.gb * 1e9))
        image_bag = root / "images.bag"
        print(f"wrote {image_bag.name}: {images:,} images, {size_of(image_bag) / 1e9:.2f} GB "
              f"in {time.perf_counter() - t:.1f} s")
        t = time.perf_counter()
        small = write_small(root, args.small)
        print(f"wrote {args.small:,} small messages in 3 formats in "
              f"{time.perf_counter() - t:.1f} s")
        print()
        print("| file | reader | messages | wall s | CPU s | messages/s | MB/s |")
        print("|---|---|---|---|---|---|---|")
        nbytes = size_of(image_bag)
        cam = config_for(["/camera/image_raw"], 0.0667, root)
        for what, fn in [
            ("bag source, timing only", lambda: source_only(image_bag, False)),
            ("bag source, every value decoded", lambda: source_only(image_bag, True)),
            ("blackbox run (hz + timeout)", lambda: whole_black_box(image_bag, cam)),
            ("rosbags rosbag1.Reader, no decoding", lambda: rosbags_reader(image_bag)),
        ]:
            n, wall, cpu = timed(fn)
            report(f"images {nbytes / 1e9:.2f} GB", what, n, nbytes, wall, cpu)
        ten = config_for([f"/bench/value_{i}" for i in range(10)], 0.001, root)
        for label, path in small.items():
            nbytes = size_of(path)
            runs: list[tuple[str, Callable[[], int]]] = [
                ("bag source, timing only", lambda p=path: source_only(p, False)),
                ("bag source, every value decoded", lambda p=path: source_only(p, True)),
                ("blackbox run (hz + timeout)", lambda p=path: whole_black_box(p, ten))]
            if label == "ROS 1 bag":
                runs.append(("rosbags rosbag1.Reader, no decoding",
                             lambda p=path: rosbags_reader(p)))
            for what, fn in runs:
                n, wall, cpu = timed(fn)
                report(f"{label} {nbytes / 1e6:.0f} MB", what, n, nbytes, wall, cpu)
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
