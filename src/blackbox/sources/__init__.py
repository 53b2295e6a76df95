"""Robot sources. ``open_source`` turns a source spec from the command line into a Source.

Specs: ``sim:thesis`` (the built-in simulated thesis robot), ``sim:PATH`` (a simulated
robot from a topology file), ``ros1`` (the master in ``ROS_MASTER_URI``) and
``ros1://HOST:PORT``.
"""

from __future__ import annotations

from typing import Any

from blackbox.config.node import ConfigError
from blackbox.sources.base import Source


def open_source(spec: str, **options: Any) -> Source:
    """Open the source named by ``spec``; ``options`` go to the source's constructor."""
    if spec.startswith("sim:"):
        from blackbox.sources.sim import open_sim

        return open_sim(spec, **options)
    if spec == "ros1" or spec.startswith("ros1://"):
        from blackbox.sources.ros1 import Ros1Source

        return Ros1Source.from_uri(spec)
    raise ConfigError(f"unknown source {spec!r}; expected sim:thesis, sim:FILE, ros1 or "
                      "ros1://HOST:PORT", "--source")
