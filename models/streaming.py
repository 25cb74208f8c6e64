"""Streaming inference: feed frames one at a time, keep the last T-1 embeddings.

Each frame goes through the per-frame CNN once (inside the step graph); its
embedding is cached, like an LLM's past keys and values, so that one step
costs one CNN pass plus the transformer over T tokens. The first T-1 frames
only fill the cache: until T frames have been seen the window is "warming"
and ``push`` returns None.

Beside the embeddings it keeps the input checks of the last T frames
(models/input_checks.py): each prediction carries the ``unloaded`` and
``out_of_range`` flags of its window next to the runtime's ``unfamiliar``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from scotti.models.errors import ModelError, ModelInputError
from scotti.models.input_checks import FrameCode, frame_codes
from scotti.models.ood import window_reasons
from scotti.models.runtime import ScottiRuntime, StepBatch, StepResult
from scotti.models.window_checks import FrameChecks


class EmbeddingCache:
    """The last ``size`` embeddings, oldest first, as a contiguous view; no reallocation.

    A ring buffer written twice: slot i and slot i + size always hold the same
    embedding, so ``buffer[head : head + size]`` is the window in order
    without a copy. Before ``size`` pushes the oldest rows are zeros.
    """

    def __init__(self, size: int, dim: int) -> None:
        if size < 0 or dim < 1:
            msg = f"an embedding cache needs size >= 0 and dim >= 1, got {size} and {dim}"
            raise ModelInputError(msg)
        self._size = size
        self._dim = dim
        self._buffer = np.zeros((2 * size, dim), dtype=np.float32)
        self._head = 0  # row of the oldest embedding in the view
        self._count = 0

    @property
    def size(self) -> int:
        return self._size

    @property
    def count(self) -> int:
        """Embeddings held, at most ``size``."""
        return min(self._count, self._size)

    def past(self) -> npt.NDArray[np.float32]:
        """(size, dim) view, oldest first; valid until the next push."""
        view = self._buffer[self._head : self._head + self._size]
        view.flags.writeable = False
        return view

    def push(self, embedding: npt.ArrayLike) -> None:
        """Append the newest embedding (dim,), dropping the oldest."""
        e = np.asarray(embedding, dtype=np.float32)
        if e.shape != (self._dim,):
            msg = f"embedding must be ({self._dim},), got {e.shape}"
            raise ModelInputError(msg)
        self._count += 1
        if self._size == 0:
            return
        # The oldest row leaves the view; its two slots take the newest embedding.
        self._buffer[self._head] = e
        self._buffer[self._head + self._size] = e
        self._head = (self._head + 1) % self._size

    def reset(self) -> None:
        self._buffer.fill(0.0)
        self._head = 0
        self._count = 0


class StreamingWindow:
    """Frames in, one prediction per frame once T frames have been seen."""

    def __init__(self, runtime: ScottiRuntime) -> None:
        if runtime.graph != "step":
            msg = f"{runtime.path.name} is a {runtime.graph} graph; streaming needs the step graph"
            raise ModelError(msg)
        self._runtime = runtime
        self._cache = EmbeddingCache(runtime.window - 1, runtime.embed_dim)
        self._checks = FrameChecks(runtime.window)
        self._seen = 0
        self.reasons: tuple[str, ...] = ()  # why the last prediction's input was flagged

    @property
    def runtime(self) -> ScottiRuntime:
        return self._runtime

    @property
    def needed(self) -> int:
        """T: frames the window must hold before it predicts."""
        return self._runtime.window

    @property
    def frames_seen(self) -> int:
        """Frames pushed since the start or the last reset."""
        return self._seen

    @property
    def frames_in_window(self) -> int:
        return min(self._seen, self.needed)

    @property
    def warming(self) -> bool:
        """True until T frames have been seen (the daemon reports "warming")."""
        return self._seen < self.needed

    def push(self, frame: npt.ArrayLike) -> StepResult | None:
        """One frame (H, 2W) of raw counts; a prediction once the window is full.

        A frame of the wrong shape raises ModelInputError and leaves the window as it was.
        """
        return push_many([self], [frame])[0]

    def past(self) -> npt.NDArray[np.float32]:
        """(T-1, E): the embeddings of the previous frames, what the next step reads."""
        return self._cache.past()

    def reset(self) -> None:
        """Forget every frame (after a long gap): the window warms up again."""
        self._cache.reset()
        self._checks.reset()
        self._seen = 0
        self.reasons = ()

    def accept_row(self, batch: StepBatch, row: int, code: FrameCode) -> StepResult | None:
        """Take row ``row`` of a step run on ``past()`` into the cache, and its frame's
        input checks (``frame_codes``) into the window's; the prediction, flagged,
        once the window is full."""
        self._cache.push(batch.embedding[row])
        verdict = self._checks.push_code(*code)
        self._seen += 1
        if self._seen < self._runtime.window:
            return None
        result = batch.row(row, verdict.flags)
        self.reasons = window_reasons(verdict.reasons, result.flags)
        return result


def push_many(
    windows: Sequence[StreamingWindow], frames: Sequence[npt.ArrayLike] | npt.NDArray[Any]
) -> list[StepResult | None]:
    """One frame into each of several windows, all of them in ONE step-graph call.

    The windows must share one runtime (one model). Same results as ``push`` on each
    window in turn, within float tolerance: the batch rows do not interact. A frame
    of the wrong shape raises ModelInputError and leaves every window as it was.
    ``frames``: (B, H, 2W) or B frames (H, 2W); raw counts, best as the wire's uint16
    (the input checks read those as they are).

    Per batch, not per frame: one stacked array in, one ``StepBatch`` out, the input
    checks of every frame in a few numpy calls (``frame_codes``); per window only its
    cache, its checks' counts and, once warm, its result.
    """
    if len(windows) != len(frames):
        msg = f"{len(windows)} windows but {len(frames)} frames"
        raise ModelInputError(msg)
    if not windows:
        return []
    runtime = windows[0].runtime
    if any(w.runtime is not runtime for w in windows):
        msg = "push_many needs windows on one runtime"
        raise ModelError(msg)
    stacked = stack_frames(frames, runtime.frame_shape)  # (B, H, 2W)
    # The checks first: they read the frames while the stacking has them in cache.
    codes = frame_codes(stacked)
    past = np.stack([w.past() for w in windows])  # (B, T-1, E)
    batch = runtime.run_steps(stacked, past)
    return [
        w.accept_row(batch, i, code) for i, (w, code) in enumerate(zip(windows, codes, strict=True))
    ]


def stack_frames(
    frames: Sequence[npt.ArrayLike] | npt.NDArray[Any], shape: tuple[int, int]
) -> npt.NDArray[Any]:
    """B frames as one (B, H, 2W) array in their own dtype (the wire's uint16 stays
    uint16, which the input checks read as it is); ModelInputError naming the first
    frame of another shape. Either form's ``push_many`` takes its frames through it."""
    if isinstance(frames, np.ndarray):
        if frames.ndim == 3 and frames.shape[1:] == shape:
            return frames
        msg = f"frame must be {shape}, got {frames.shape[1:]}"
        raise ModelInputError(msg)
    arrays = [np.asarray(f) for f in frames]
    for a in arrays:
        if a.shape != shape:
            msg = f"frame must be {shape}, got {a.shape}"
            raise ModelInputError(msg)
    return np.stack(arrays)
