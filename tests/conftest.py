"""Shared fixtures: every ``tests/support/fixtures_*.py`` is loaded as a plugin.

Keeping fixtures in one module per concern (broker, serial pty, models) lets
each room's tests grow without editing this file.
"""

from __future__ import annotations

from pathlib import Path

pytest_plugins = sorted(
    f"tests.support.{p.stem}" for p in (Path(__file__).parent / "support").glob("fixtures_*.py")
)
