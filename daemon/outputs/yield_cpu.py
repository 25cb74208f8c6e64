"""Put this process below everything else on the host for the CPU.

The network outputs' process (front.py) serves readers the daemon does not wait
for; when the host's cores are short, the reading and publishing of poses must
not wait for it. ``nice 19`` alone is not enough for that: the scheduler still
gives a niced process a share and lets it finish its slice before a waking
daemon runs (a thousand web readers took MQTT's p99 from 10 to 50 ms on two
cores). Linux's SCHED_IDLE class runs a process only when nothing else wants the
CPU and lets any other task preempt it at once.
"""

from __future__ import annotations

import contextlib
import os
from typing import Final

NICENESS: Final = 19  # the fallback where SCHED_IDLE is not offered (not Linux)


def yield_cpu_to_others() -> str:
    """SCHED_IDLE for this process where the OS has it, else nice 19; which one it got."""
    idle = getattr(os, "SCHED_IDLE", None)
    if idle is not None:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, idle, os.sched_param(0))
            return "SCHED_IDLE"
    with contextlib.suppress(OSError):
        os.nice(NICENESS)
        return f"nice {NICENESS}"
    return "unchanged"


def scheduling_of(pid: int) -> str:
    """What ``yield_cpu_to_others`` would report for ``pid`` now (for tests and status)."""
    idle = getattr(os, "SCHED_IDLE", None)
    if idle is not None and os.sched_getscheduler(pid) == idle:
        return "SCHED_IDLE"
    return f"nice {os.getpriority(os.PRIO_PROCESS, pid)}"
