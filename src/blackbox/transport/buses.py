"""Which bus a black box or a station talks on: DDS on a LAN (the default), Zenoh routers
across sites. Its own module, so that ``participant`` (DDS and the bus Protocol) and
``zenoh_bus`` (which implements that Protocol) do not import each other."""

from __future__ import annotations

from blackbox.transport.participant import Bus, HealthBus, TransportSettings


def open_bus(settings: TransportSettings, origin: str | None = None) -> HealthBus:
    """The bus ``settings`` name: Zenoh when it has endpoints, else DDS. ``origin`` (the
    robot id, or a station's name) is what Zenoh writers publish under."""
    if settings.zenoh is not None:
        from blackbox.transport.zenoh_bus import ZenohBus
        return ZenohBus.open(settings.zenoh, origin)
    return Bus.open(settings)
