"""A Zenoh router inside a ``blackbox`` process (``blackbox router``).

Neither Debian nor PyPI ship ``zenohd``; the ``eclipse-zenoh`` package can itself be the
router robots and stations at different sites connect to. Multicast scouting stays off, so a
router is reached only where it is configured, never discovered on a LAN by accident.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import zenoh

from blackbox.transport.zenoh_bus import ENDPOINT, ZenohError, _json_list, apply_tls, first_line


@dataclass(frozen=True, slots=True)
class RouterSettings:
    """Where the router listens, which routers it connects to (a mesh across sites), and its
    TLS files (``tls/`` endpoints need ``certificate`` and ``private_key``; ``root_ca`` also
    makes it verify the routers it connects to)."""

    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    root_ca: str | None = None
    certificate: str | None = None
    private_key: str | None = None

    def __post_init__(self) -> None:
        for endpoint in (*self.listen, *self.connect):
            if not ENDPOINT.match(endpoint):
                raise ValueError(f"not a Zenoh endpoint: {endpoint!r} "
                                 "(expected e.g. tcp/127.0.0.1:7447 or tls/host:7447)")
        if any(e.startswith("tls/") for e in self.listen) and self.certificate is None:
            raise ValueError("a tls/ endpoint needs --zenoh-certificate and --zenoh-key")

    def config(self) -> zenoh.Config:
        config = zenoh.Config()
        config.insert_json5("mode", '"router"')
        config.insert_json5("listen/endpoints", _json_list(self.listen))
        config.insert_json5("connect/endpoints", _json_list(self.connect))
        config.insert_json5("scouting/multicast/enabled", "false")
        apply_tls(config, self.root_ca, self.certificate, self.private_key)
        return config


def open_router(settings: RouterSettings) -> Any:
    """The running router's session (close it to stop the router)."""
    try:
        return zenoh.open(settings.config())
    except Exception as exc:
        raise ZenohError(f"cannot start a Zenoh router on "
                         f"{', '.join(settings.listen)}: {first_line(exc)}") from None
