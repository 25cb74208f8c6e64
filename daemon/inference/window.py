"""The model's window over paired frames: T frames, each embedded once.

A thin layer over ``models.streaming.StreamingWindow``: a new frame costs one
step of the streaming graph (its CNN pass + the transformer over the cached
embeddings of the previous T-1 frames). Until T frames are in, there is no
prediction and the window reports that it is warming.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scotti.models.runtime import ScottiRuntime, StepResult
from scotti.models.streaming import StreamingWindow, push_many


@dataclass(frozen=True)
class WindowOutput:
    result: StepResult | None  # None while warming
    frames_in_window: int
    needed: int  # T
    reasons: tuple[str, ...] = ()  # why the result is flagged (unloaded, out_of_range, ...)

    @property
    def warming(self) -> bool:
        return self.result is None


class Window:
    """``push(counts) -> WindowOutput``; ``restart()`` after a gap, a drop or a reconnect."""

    def __init__(self, runtime: ScottiRuntime) -> None:
        self._streaming = StreamingWindow(runtime)
        self.restarts = 0

    @property
    def needed(self) -> int:
        return self._streaming.needed

    @property
    def frames_in_window(self) -> int:
        return self._streaming.frames_in_window

    def push(self, counts: npt.NDArray[np.uint16]) -> WindowOutput:
        """One paired frame (H, 2W) of raw counts; normalisation is inside the graph."""
        streaming = self._streaming
        result = streaming.push(counts)
        reasons = streaming.reasons if result is not None else ()
        return WindowOutput(result, streaming.frames_in_window, streaming.needed, reasons)

    def restart(self) -> None:
        """Forget every frame: the next T frames warm the window up again."""
        if self._streaming.frames_seen:
            self.restarts += 1
        self._streaming.reset()

    @staticmethod
    def push_batch(
        windows: Sequence[Window], counts: Sequence[npt.NDArray[np.uint16]]
    ) -> list[WindowOutput]:
        """One paired frame into each window, in one call of the shared model (see
        ``models.streaming.push_many``); a bad frame raises and leaves every window as it was."""
        streams = [w._streaming for w in windows]  # Window's own state: this is its method
        results = push_many(streams, counts)
        if not streams:
            return []
        needed = streams[0].needed  # one runtime, one T
        return [
            WindowOutput(r, min(s.frames_seen, needed), needed, s.reasons if r is not None else ())
            for r, s in zip(results, streams, strict=True)
        ]
