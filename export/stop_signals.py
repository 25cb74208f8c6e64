"""SIGTERM and SIGINT as a request to stop training after the current step.

A long CPU run is stopped from outside: Ctrl-C, ``kill``, a session or job
scheduler ending. Dying mid-step would lose everything since the last
checkpoint; instead the first signal only sets a flag, the training loop
sees it before its next step, writes ``last.pt`` and returns, and the
process exits 0. The first signal also puts the previous handlers back, so
a second one acts as it would have without us (SIGINT raises
KeyboardInterrupt, SIGTERM ends the process at once).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


class StopRequest:
    """Which signal asked the run to stop, if one did."""

    def __init__(self) -> None:
        self.signal_name: str | None = None

    @property
    def requested(self) -> bool:
        return self.signal_name is not None


@contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    """While inside, SIGTERM and SIGINT set the request instead of ending the process.

    Only the main thread may install signal handlers; elsewhere the request is
    never set and the signals keep their usual effect.
    """
    request = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request
        return
    previous: dict[int, Any] = {}

    def restore() -> None:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        previous.clear()

    def handle(signum: int, _frame: FrameType | None) -> None:
        request.signal_name = signal.Signals(signum).name
        restore()  # a second signal is not caught: it stops the process at once

    for signum in STOP_SIGNALS:
        previous[signum] = signal.signal(signum, handle)
    try:
        yield request
    finally:
        restore()
