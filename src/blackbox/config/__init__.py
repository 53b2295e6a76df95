"""Configuration loading: the native format and the tug_observers format."""

from blackbox.config.node import ConfigError, ConfigNode

__all__ = ["ConfigError", "ConfigNode"]
