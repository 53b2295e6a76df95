"""Throw-away plug-ins: one observer type and one source, each in one file, registered the
way every built-in one is (see tests/test_plugins.py)."""
