"""The reference docs stay references: short enough to read (issue 39's limits)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
LIMITS = {"docs/mqtt.md": 500, "docs/evaluation.md": 600, "export/TRAINING.md": 500}


@pytest.mark.parametrize(("doc", "most"), LIMITS.items())
def test_doc_stays_within_its_length(doc: str, most: int) -> None:
    lines = (ROOT / doc).read_text().count("\n")
    assert 0 < lines <= most, f"{doc}: {lines} lines (at most {most}); history goes to git"


def test_daemon_root_holds_only_its_shared_modules() -> None:
    # The service lives in sub-rooms (daemon/__init__.py names them); the root keeps
    # the exception root and the waiting helpers that every room shares.
    modules = sorted(p.name for p in (ROOT / "daemon").glob("*.py"))
    assert len(modules) <= 14, modules
    assert modules == ["__init__.py", "errors.py", "waiting.py"]
