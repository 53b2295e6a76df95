"""Robot sources. ``open_source`` turns a source spec from the command line into a Source.

Each kind of source registers its URL scheme in :data:`~blackbox.sources.base.SOURCES`
from its own module; the built-in ones are ``sim:thesis`` / ``sim:PATH`` (the simulated
robot), ``ros1`` / ``ros1://HOST:PORT`` (a live ROS 1 master) and ``bag:FILE`` (a
recorded ROS 1 bag, rosbag2 directory or MCAP file, replayed).
"""

from __future__ import annotations

from blackbox.config.node import ConfigError
from blackbox.sources.base import Source, SourceOptions, source_kind


def open_source(spec: str, options: SourceOptions | None = None) -> Source:
    """Open the source named by ``spec``.

    Raises ``ConfigError`` (for ``--source``) when no source has the scheme or when
    ``options`` ask for what the source cannot do.
    """
    options = options or SourceOptions()
    kind = source_kind(spec)
    caps = kind.capabilities
    if options.faults is not None and not caps.fault_injection:
        raise ConfigError(f"{spec} cannot inject faults (--faults needs a source that can, "
                          "such as sim:...)", "--source")
    if options.rate is not None and not caps.replay:
        raise ConfigError(f"{spec} is not a recording (--rate needs a source that replays "
                          "one, such as bag:FILE)", "--source")
    if options.rate is not None and not options.realtime:
        raise ConfigError("--rate plays in real time; it cannot go with --simulated-clock",
                          "--rate")
    if options.rate is not None and not options.rate > 0:
        raise ConfigError(f"--rate must be a positive number, got {options.rate}", "--rate")
    if not options.realtime and not caps.simulated_clock:
        raise ConfigError(f"{spec} runs in real time only (--simulated-clock needs a "
                          "simulated source, such as sim:...)", "--source")
    return kind.open(spec, options)
