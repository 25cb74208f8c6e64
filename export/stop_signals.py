"""SIGTERM and SIGINT as a request to stop training after the current step.

A long CPU run is stopped from outside: Ctrl-C, ``kill``, a session or job
scheduler ending. Dying mid-step would lose everything since the last
checkpoint; instead the first signal only sets a flag, the training loop
sees it before its next step, writes ``last.pt`` and returns, and the
process exits 0. A signal also puts its own previous handler back, so the
same signal again acts as it would have without us (a second Ctrl-C raises
KeyboardInterrupt, a second SIGTERM ends the process at once). The other
one stays caught: under torchrun a Ctrl-C reaches every rank as SIGINT and
torchrun then sends each a SIGTERM, which must not cut the stop short.
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

    def restore(*signums: int) -> None:
        for signum in signums:
            if signum in previous:
                signal.signal(signum, previous.pop(signum))

    def handle(signum: int, _frame: FrameType | None) -> None:
        request.signal_name = request.signal_name or signal.Signals(signum).name
        restore(signum)  # the same signal again is not caught: it stops the process at once

    for signum in STOP_SIGNALS:
        previous[signum] = signal.signal(signum, handle)
    try:
        yield request
    finally:
        restore(*STOP_SIGNALS)
