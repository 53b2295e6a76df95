"""The ROS 2 source (``--source ros2`` or ``ros2:DOMAIN_ID``): see :mod:`.source`."""

from blackbox.sources.ros2.source import Ros2Settings, Ros2Source, domain_id_from_spec

__all__ = ["Ros2Settings", "Ros2Source", "domain_id_from_spec"]
