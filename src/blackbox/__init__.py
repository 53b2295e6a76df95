"""Robot black box: non-intrusive fault detection, diagnosis and health recording for robots."""

__version__ = "0.1.0"
