"""Run a ``scotti`` verb on models whose window T is not the contract's 40.

    python experiments/any_window.py T VERB ARGS...

The runtime refuses a model whose T differs from ``contract.WINDOW`` (the
daemon's models must all be T=40). The sweep's T=20 models are scored and
timed through the very same code with the contract's T set to theirs in this
one process; nothing else in the path depends on T. Shipping a T=20 model
would need that contract to change.
"""

from __future__ import annotations

import sys

from scotti.cli.main import main
from scotti.models import contract


def with_window(window: int) -> None:
    contract.WINDOW = window  # type: ignore[misc]  # read at load time by the runtime's check


if __name__ == "__main__":
    with_window(int(sys.argv[1]))
    raise SystemExit(main(sys.argv[2:]))
