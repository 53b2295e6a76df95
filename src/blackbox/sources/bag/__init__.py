"""Recorded robots: ROS 1 bags, rosbag2 directories (sqlite3, MCAP) and MCAP files,
replayed through the same observers and diagnosis as a live robot (docs/bags.md)."""

from blackbox.sources.bag.records import BagCorrupt, RecordedMessage, RecordedTopic
from blackbox.sources.bag.source import BagSource, open_bag, open_scanner, placeholder_publisher

__all__ = [
    "BagCorrupt",
    "BagSource",
    "RecordedMessage",
    "RecordedTopic",
    "open_bag",
    "open_scanner",
    "placeholder_publisher",
]
