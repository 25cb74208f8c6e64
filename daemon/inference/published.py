"""What one prediction publishes of its action, progress and repetition count.

The one rule, shared by the daemon's pipeline and every count the docs claim
(experiments/demo_progress.py): a prediction that a flag withholds
(``models.ood.withheld``: unloaded, out_of_range, unfamiliar) publishes no
action, no progress and no count, and the repetition counter neither counts
nor forgets; otherwise standing publishes no progress and the counter gives
the count. A window restart starts the counter over: that is the caller's
(``RepetitionCounter.reset``), as only the caller sees the frames.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple

from scotti.daemon.inference.repetitions import RepetitionCounter
from scotti.models.contract import NO_ACTION, has_progress
from scotti.models.ood import withheld


class Published(NamedTuple):
    action: int  # NO_ACTION while withheld
    progress: float  # NaN while withheld or standing
    repetition: int  # -1: none (withheld, or an action without repetitions)
    withheld: str | None  # the flag that withheld it, None if published


def publish(
    action: int, progress: float, flags: Iterable[str], counter: RepetitionCounter
) -> Published:
    """The published form of one prediction (``action``: the most likely one), the
    counter updated as the daemon updates it."""
    held_back = withheld(flags)
    if held_back is not None:
        # Nobody there, not a pressure map, or unlike anything learnt: no action, no
        # progress, and the repetition counter neither counts nor forgets.
        return Published(NO_ACTION, float("nan"), -1, held_back)
    if not has_progress(action):
        progress = float("nan")  # the progress head says nothing while standing
    return Published(action, progress, counter.update(action, progress), None)
