"""Live ROS 1 robots, observed through the master's XML-RPC API and hand-made TCPROS.

Needs no ROS installation on the black box: only the standard library, psutil and rosbags.
"""

from blackbox.sources.ros1.source import Ros1Settings, Ros1Source, master_uri_from_spec

__all__ = ["Ros1Settings", "Ros1Source", "master_uri_from_spec"]
