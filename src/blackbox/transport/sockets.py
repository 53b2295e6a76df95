"""Keep Cyclone's sockets on the configured network interface.

Cyclone DDS sends only on the interfaces its configuration names, but it binds its
receiving (unicast discovery and data) sockets to the wildcard address 0.0.0.0 whatever the
configuration says (``ddsi_udp_create_conn``: ``bind_to_any`` for receive sockets, no
option to change it). So a black box configured for loopback would still accept datagrams
arriving from any network. After the participant is created, :func:`pin_new_sockets`
binds each new wildcard UDP socket of this process to the configured interface with
``SO_BINDTODEVICE`` (Linux; needs root or ``CAP_NET_RAW`` before Linux 5.7): the kernel
then delivers to it only datagrams that arrived on that interface.

Which interface: the one ``<NetworkInterface name=...>`` (or ``address=...``) of the
Cyclone configuration names; ``lo`` for the built-in loopback configuration. With several
interfaces a socket cannot be pinned to all of them, and nothing is pinned (the sockets
stay on the wildcard, as Cyclone made them): docs/health.md says so.
"""

from __future__ import annotations

import os
import re
import socket
from pathlib import Path

import psutil

SO_BINDTODEVICE = getattr(socket, "SO_BINDTODEVICE", 25)
_NAME = re.compile(r"<NetworkInterface\b[^>]*\bname\s*=\s*\"([^\"]+)\"", re.IGNORECASE)
_ADDRESS = re.compile(r"<NetworkInterface\b[^>]*\baddress\s*=\s*\"([^\"]+)\"", re.IGNORECASE)


def configured_interface(config: str) -> str | None:
    """The one network interface a Cyclone configuration (XML or ``file://``) names."""
    text = config
    if config.strip().startswith("file://"):
        try:
            text = Path(config.strip()[len("file://"):]).read_text()
        except OSError:
            return None
    names = set(_NAME.findall(text))
    for address in _ADDRESS.findall(text):
        for name, addrs in psutil.net_if_addrs().items():
            if any(a.address == address for a in addrs):
                names.add(name)
    return names.pop() if len(names) == 1 else None


def udp_wildcard_sockets() -> dict[int, int]:
    """This process's IPv4/IPv6 UDP sockets bound to the wildcard address: inode -> fd."""
    out: dict[int, int] = {}
    for conn in psutil.Process().net_connections(kind="udp"):
        if conn.fd >= 0 and conn.laddr and conn.laddr.ip in ("0.0.0.0", "::"):
            try:
                out[os.fstat(conn.fd).st_ino] = conn.fd
            except OSError:
                continue
    return out


def bound_device(fd: int) -> str:
    """The interface a socket is pinned to ('' if none)."""
    s = socket.socket(fileno=os.dup(fd))
    try:
        return s.getsockopt(socket.SOL_SOCKET, SO_BINDTODEVICE, 64).rstrip(b"\0").decode()
    finally:
        s.close()


def pin_new_sockets(before: set[int], interface: str) -> list[str]:
    """Pin every wildcard UDP socket not in ``before`` (inodes) to ``interface``.

    Returns the errors (empty when all were pinned).
    """
    errors: list[str] = []
    for inode, fd in udp_wildcard_sockets().items():
        if inode in before:
            continue
        s = socket.socket(fileno=os.dup(fd))
        try:
            s.setsockopt(socket.SOL_SOCKET, SO_BINDTODEVICE, interface.encode())
        except OSError as exc:
            errors.append(f"fd {fd}: {exc.strerror}")
        finally:
            s.close()
    return errors
