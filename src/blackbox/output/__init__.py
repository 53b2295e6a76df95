"""Local outputs of a run: JSON lines files and the live status view."""
