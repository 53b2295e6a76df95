"""Caller ids the black box gives its TCPROS connections.

A rospy publisher keeps one connection per caller id: when a second subscriber connects
with the id of an existing one, the older connection is dropped. Two black boxes on one
robot that both said ``/blackbox`` therefore took turns disconnecting each other. Every
:class:`~blackbox.sources.ros1.source.Ros1Source` gets its own id, in the style of
``rospy.init_node(..., anonymous=True)``: ``/blackbox_<host>_<pid>_<n>``, where ``n``
counts the sources opened in this process. The prefix is configurable
(``Ros1Settings.caller_id``); a fully given id is used as is.
"""

from __future__ import annotations

import itertools
import os
import re
import socket

DEFAULT_PREFIX = "/blackbox"
_counter = itertools.count(1)
_NOT_NAME = re.compile(r"[^A-Za-z0-9_]")


def is_black_box(caller: str) -> bool:
    """A black box's own node or connection (this one's or another's, including the
    ``--publish-diagnostics`` publisher): no part of the robot it watches."""
    return caller == DEFAULT_PREFIX or caller.startswith(DEFAULT_PREFIX + "_")


def valid_caller_id(name: str) -> bool:
    """A global ROS graph name: ``/`` then segments of letters, digits and ``_``."""
    return re.fullmatch(r"(/[A-Za-z][A-Za-z0-9_]*)+", name) is not None


def unique_caller_id(prefix: str = DEFAULT_PREFIX, host: str | None = None,
                     pid: int | None = None) -> str:
    """``<prefix>_<host>_<pid>_<n>``, unique per source on this host.

    The host name is reduced to ROS name characters (``my-pi.local`` -> ``my_pi_local``).
    """
    if not valid_caller_id(prefix):
        raise ValueError(f"caller id prefix {prefix!r} is not a global ROS name "
                         "(for example /blackbox)")
    host_part = _NOT_NAME.sub("_", host if host is not None else socket.gethostname())
    return f"{prefix}_{host_part or 'host'}_{os.getpid() if pid is None else pid}" \
           f"_{next(_counter)}"
