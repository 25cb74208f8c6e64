"""The outputs' own thread: what the devices hand over is written there, not on the loop.

Building a Foxglove skeleton, encoding protobuf and JSON, writing MCAP,
pushing LSL samples and rendering the browser's events cost a little per
frame, and a dozen devices at 16 Hz make that a couple of hundred frames a
second. Done on the event loop, it would delay every device's serial reader
and MQTT publisher by that much. So the devices only append to a bounded
queue here (no work, no wait), and one thread takes the items in order and
calls the outputs. When the outputs fall behind, the oldest *prediction* is
dropped and counted (the newer one is worth more to a live view); a status
is never dropped, so an MCAP file still ends with each device ``offline``.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Final

if TYPE_CHECKING:
    from scotti.daemon.frames.pipeline import Prediction
    from scotti.daemon.mqtt.schemas import Status

log = logging.getLogger(__name__)

FRAMES_PER_DEVICE: Final = 16  # a second of frames per device may wait before drops
DROP_LOG_EVERY_S: Final = 10.0  # a full queue is logged at most this often (and counted)
ABANDON_WAIT_S: Final = 1.0  # after close's timeout: for the item in hand to finish


@dataclasses.dataclass(frozen=True, slots=True)
class Item:
    """One thing a device handed over: its prediction or its status."""

    device: str
    prediction: Prediction | None = None
    status: Status | None = None


class OutputThread:
    """``submit`` from the event loop; ``handle`` runs on the thread, item by item."""

    def __init__(self, handle: Callable[[Item], None], *, devices: int) -> None:
        self.handle = handle
        self.max_items = FRAMES_PER_DEVICE * max(1, devices)
        self.dropped = 0  # predictions the outputs never saw because they fell behind
        # The same, per device: each device's health reports its own. Written by
        # ``submit`` only, so read it from the thread that submits (the event loop).
        self._dropped_of: collections.Counter[str] = collections.Counter()
        self.abandoned = 0  # items still queued when ``close`` gave up waiting
        self.failed = 0  # items whose ``handle`` raised (the outputs count their own)
        self._items: collections.deque[Item] = collections.deque()
        self._wake = threading.Condition()
        self._closing = False
        self._logged_drop = float("-inf")
        self._thread = threading.Thread(target=self._run, name="scotti-outputs", daemon=True)
        self._thread.start()

    def submit(self, item: Item) -> None:
        with self._wake:
            if self._closing:
                return
            if len(self._items) >= self.max_items and self._drop_oldest_prediction():
                self._log_drop()
            self._items.append(item)
            self._wake.notify()

    def dropped_of(self, device: str) -> int:
        """The predictions of ``device`` that were dropped (see ``dropped``)."""
        return self._dropped_of[device]

    def close(self, timeout_s: float) -> bool:
        """Write what is queued, then end the thread; False if it did not end in time.
        Then what is still queued is given up (``abandoned``), so that the outputs are
        not closed while the thread is still writing into them for long: it ends after
        the item in hand (waited for up to ``ABANDON_WAIT_S`` more).
        Blocks: call it from a worker thread (``asyncio.to_thread``)."""
        with self._wake:
            self._closing = True
            self._wake.notify()
        self._thread.join(timeout_s)
        if not self._thread.is_alive():
            return True
        with self._wake:
            self.abandoned = len(self._items)
            self._items.clear()
        self._thread.join(ABANDON_WAIT_S)
        return False

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._items and not self._closing:
                    self._wake.wait()
                if not self._items:
                    return  # closing and everything written (or given up)
                item = self._items.popleft()
            try:
                self.handle(item)
            except Exception:  # the thread outlives a bad item: the next ones still go out
                self.failed += 1
                if self.failed == 1:
                    log.warning("outputs: an item failed (counted from now on)", exc_info=True)

    def _drop_oldest_prediction(self) -> bool:
        for k, queued in enumerate(self._items):
            if queued.prediction is not None:
                del self._items[k]
                self.dropped += 1
                self._dropped_of[queued.device] += 1
                return True
        return False  # only statuses queued: they all stay (there are few)

    def _log_drop(self) -> None:
        now = time.monotonic()
        if now - self._logged_drop >= DROP_LOG_EVERY_S:
            self._logged_drop = now
            log.warning(
                "outputs fall behind: dropped the oldest prediction (%d so far)", self.dropped
            )
