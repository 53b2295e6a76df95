"""Robot sources. ``open_source`` turns a source spec from the command line into a Source.

Each kind of source registers its URL scheme in :data:`~blackbox.sources.base.SOURCES`
from its own module; the built-in ones are ``sim:thesis`` / ``sim:PATH`` (the simulated
robot) and ``ros1`` / ``ros1://HOST:PORT`` (a live ROS 1 master).
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
    if not options.realtime and not caps.simulated_clock:
        raise ConfigError(f"{spec} runs in real time only (--simulated-clock needs a "
                          "simulated source, such as sim:...)", "--source")
    return kind.open(spec, options)
