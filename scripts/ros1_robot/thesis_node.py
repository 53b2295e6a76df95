#!/usr/bin/python3
"""One node of the thesis robot (section 6.2.1), as a real rospy node.

    thesis_node.py camera|audio|signal [--rate HZ]

Runs under Debian's ``/usr/bin/python3`` (where rospy lives). Each node reads its private
parameters through rospy's parameter cache on every cycle, so the fault injector changes
them at run time with a plain ``setParam`` on the master; the node hears about it through a
parameter subscription:

- ``~rate`` (Hz; 0 publishes nothing while the node stays alive)
- ``~hog`` (percent of one core burnt by a busy thread, 0 = off) and ``~leak`` (bytes per
  second the node allocates and keeps; back to 0 frees it), on every node
- signal only: ``~offset``, ``~scale``, ``~stuck`` (1 freezes the value at the last one
  sent) and ``~drift`` (units per second added since the drift was set)

- camera: ``/usb_cam`` publishes ``/usb_cam/image_raw`` (sensor_msgs/Image 640x480 rgb8) at 15 Hz
- audio: ``/audio_capture`` publishes ``/audio`` (std_msgs/UInt8MultiArray, 480 bytes) at 33.3 Hz
- signal: ``/Signal_generator`` subscribes to both and publishes ``/signal`` (std_msgs/Float64,
  offset + scale * (15 +- 0.5 uniform)) at 15 Hz
"""

import argparse
import contextlib
import random
import threading
import time

import rospy
from sensor_msgs.msg import Image
from std_msgs.msg import Float64, UInt8MultiArray

ROLES = {
    "camera": ("usb_cam", 15.0),
    "audio": ("audio_capture", 33.333),
    "signal": ("Signal_generator", 15.0),
}


def _param(name, default):
    try:
        return float(rospy.get_param_cached(name, default))
    except (KeyError, TypeError, ValueError):
        return default


def _loop(make, publisher, rate):
    """Publish ``make()`` at ``~rate`` Hz, re-reading the rate every cycle."""
    next_t = time.monotonic()
    while not rospy.is_shutdown():
        hz = _param("~rate", rate)
        if hz > 0:
            publisher.publish(make())
            next_t += 1.0 / hz
        else:
            next_t += 0.1
        delay = next_t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            next_t = time.monotonic()


def _trouble():
    """Burn ``~hog`` percent of one core and keep ``~leak`` bytes per second, from a thread
    of this process (so the node's own pid shows it, as a real CPU or memory fault would)."""
    kept = []
    period = 0.02
    while not rospy.is_shutdown():
        hog = min(max(_param("~hog", 0.0), 0.0), 100.0)
        leak = max(_param("~leak", 0.0), 0.0)
        if leak > 0:
            kept.append(bytearray(b"\x01") * int(leak * period))
        elif kept:
            kept.clear()
        if hog > 0:
            end = time.monotonic() + period * hog / 100.0
            while time.monotonic() < end:
                pass
            time.sleep(period * (1.0 - hog / 100.0))
        else:
            time.sleep(period)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("role", choices=sorted(ROLES))
    parser.add_argument("--rate", type=float, default=None, help="publishing rate in Hz")
    args, _ = parser.parse_known_args()
    name, default_rate = ROLES[args.role]
    rate = default_rate if args.rate is None else args.rate
    rospy.init_node(name, anonymous=False, disable_signals=False)
    rospy.set_param("~rate", rate)
    rospy.set_param("~hog", 0.0)
    rospy.set_param("~leak", 0.0)
    threading.Thread(target=_trouble, daemon=True).start()
    if args.role == "camera":
        pub = rospy.Publisher("/usb_cam/image_raw", Image, queue_size=2)
        msg = Image(height=480, width=640, encoding="rgb8", is_bigendian=0, step=640 * 3,
                    data=bytes(640 * 480 * 3))
        msg.header.frame_id = "usb_cam"

        def make():
            msg.header.stamp = rospy.Time.now()
            msg.header.seq += 1
            return msg

        _loop(make, pub, rate)
    elif args.role == "audio":
        pub = rospy.Publisher("/audio", UInt8MultiArray, queue_size=5)
        chunk = UInt8MultiArray(data=bytes(480))
        _loop(lambda: chunk, pub, rate)
    else:
        for name, default in (("~offset", 0.0), ("~scale", 1.0), ("~stuck", 0.0),
                              ("~drift", 0.0)):
            rospy.set_param(name, default)
        counts = {"image": 0, "audio": 0}
        rospy.Subscriber("/usb_cam/image_raw", Image,
                         lambda m: counts.__setitem__("image", counts["image"] + 1),
                         queue_size=1, buff_size=2 ** 22)
        rospy.Subscriber("/audio", UInt8MultiArray,
                         lambda m: counts.__setitem__("audio", counts["audio"] + 1),
                         queue_size=5)
        pub = rospy.Publisher("/signal", Float64, queue_size=5)

        last = {"value": 15.0, "drift_since": None}

        def value():
            if _param("~stuck", 0.0):
                return Float64(last["value"])
            drift = _param("~drift", 0.0)
            if drift and last["drift_since"] is None:
                last["drift_since"] = time.monotonic()
            elif not drift:
                last["drift_since"] = None
            since = last["drift_since"]
            extra = drift * (time.monotonic() - since) if since is not None else 0.0
            base = 15.0 + random.uniform(-0.5, 0.5)
            out = _param("~offset", 0.0) + _param("~scale", 1.0) * base + extra
            last["value"] = out
            return Float64(out)

        _loop(value, pub, rate)


if __name__ == "__main__":
    with contextlib.suppress(rospy.ROSInterruptException):
        main()
