#!/usr/bin/python3
"""One node of the thesis robot (section 6.2.1), as a real rospy node.

    thesis_node.py camera|audio|signal [--rate HZ]

Runs under Debian's ``/usr/bin/python3`` (where rospy lives). Each node reads its private
parameters ``~rate`` (Hz), ``~offset`` and ``~scale`` (signal only) through rospy's parameter
cache on every cycle, so the fault injector changes them at run time with a plain
``setParam`` on the master; the node hears about it through a parameter subscription.

- camera: ``/usb_cam`` publishes ``/usb_cam/image_raw`` (sensor_msgs/Image 640x480 rgb8) at 15 Hz
- audio: ``/audio_capture`` publishes ``/audio`` (std_msgs/UInt8MultiArray, 480 bytes) at 33.3 Hz
- signal: ``/Signal_generator`` subscribes to both and publishes ``/signal`` (std_msgs/Float64,
  offset + scale * (15 +- 0.5 uniform)) at 15 Hz
"""

import argparse
import contextlib
import random
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("role", choices=sorted(ROLES))
    parser.add_argument("--rate", type=float, default=None, help="publishing rate in Hz")
    args, _ = parser.parse_known_args()
    name, default_rate = ROLES[args.role]
    rate = default_rate if args.rate is None else args.rate
    rospy.init_node(name, anonymous=False, disable_signals=False)
    rospy.set_param("~rate", rate)
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
        rospy.set_param("~offset", 0.0)
        rospy.set_param("~scale", 1.0)
        counts = {"image": 0, "audio": 0}
        rospy.Subscriber("/usb_cam/image_raw", Image,
                         lambda m: counts.__setitem__("image", counts["image"] + 1),
                         queue_size=1, buff_size=2 ** 22)
        rospy.Subscriber("/audio", UInt8MultiArray,
                         lambda m: counts.__setitem__("audio", counts["audio"] + 1),
                         queue_size=5)
        pub = rospy.Publisher("/signal", Float64, queue_size=5)

        def value():
            base = 15.0 + random.uniform(-0.5, 0.5)
            return Float64(_param("~offset", 0.0) + _param("~scale", 1.0) * base)

        _loop(value, pub, rate)


if __name__ == "__main__":
    with contextlib.suppress(rospy.ROSInterruptException):
        main()
