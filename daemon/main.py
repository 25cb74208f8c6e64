"""``scotti-daemon``: the live service (filled in by the daemon issue)."""

from __future__ import annotations

import sys


def main() -> int:
    print("scotti-daemon: not built yet; see README.md", file=sys.stderr)
    return 2
