"""The model's window over paired frames: T frames, each embedded once.

A thin layer over ``models.streaming.StreamingWindow``: a new frame costs one
step of the streaming graph (its CNN pass + the transformer over the cached
embeddings of the previous T-1 frames). Until T frames are in, there is no
prediction and the window reports that it is warming.

A streaming-native export (``KvStepRuntime``) runs through
``models.kv_streaming.KvStreamingWindow`` instead: the same outputs, a key/value
cache per window (docs/streaming-native.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scotti.models import kv_streaming
from scotti.models.errors import ModelError
from scotti.models.kv_streaming import KvStepRuntime, KvStreamingWindow
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

    def __init__(self, runtime: ScottiRuntime | KvStepRuntime) -> None:
        self._streaming: StreamingWindow | KvStreamingWindow = (
            KvStreamingWindow(runtime)
            if isinstance(runtime, KvStepRuntime)
            else StreamingWindow(runtime)
        )
        self.restarts = 0

    @property
    def needed(self) -> int:
        return self._streaming.needed

    @property
    def frames_in_window(self) -> int:
        return min(self._streaming.frames_seen, self._streaming.needed)

    def push(self, counts: npt.NDArray[np.uint16]) -> WindowOutput:
        """One paired frame (H, 2W) of raw counts; normalisation is inside the graph."""
        streaming = self._streaming
        result = streaming.push(counts)
        reasons = streaming.reasons if result is not None else ()
        return WindowOutput(result, self.frames_in_window, streaming.needed, reasons)

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
        paper = [s for s in streams if isinstance(s, StreamingWindow)]
        if len(paper) == len(streams):
            results = push_many(paper, counts)
        else:  # windows on one runtime: all of them key/value windows, or push_many refuses
            kv = [s for s in streams if isinstance(s, KvStreamingWindow)]
            if len(kv) != len(streams):
                msg = "push_batch needs windows on one runtime"
                raise ModelError(msg)
            results = kv_streaming.push_many(kv, counts)
        if not streams:
            return []
        needed = streams[0].needed  # one runtime, one T
        return [
            WindowOutput(r, min(s.frames_seen, needed), needed, s.reasons if r is not None else ())
            for r, s in zip(results, streams, strict=True)
        ]
