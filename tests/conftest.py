"""Shared test fixtures and paths."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT / "data" / "shared"
"""Vendored copies of the shared reference inputs (tug configs, thesis setup, DXC)."""
