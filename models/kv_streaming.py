"""Streaming inference for the streaming-native model: a per-layer key/value cache.

The paper form's step reruns the transformer over all T+1 tokens each frame
(models/streaming.py caches only the CNN's embeddings). The streaming-native form
(``arch: "streaming"``, export/model_streaming.py) has relative positions and causal
attention, so each frame's keys and values at every layer never change once
computed: its step graph takes the new frame, the cached rows of the previous T-1
frames and which of them hold a frame, and returns the heads and the new frame's
row. A step costs the CNN on one frame and 2 tokens through the layers.

Its step graph says so in its metadata (``scotti.graph`` = ``step_kv``, so a
runtime that only knows the paper form's contract refuses it in one line); its
window graph has the paper form's I/O and loads in ``ScottiRuntime``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scotti.models import contract as c
from scotti.models.errors import ModelContractError, ModelError, ModelInputError
from scotti.models.graph_checks import check_metadata, ood_stats, open_session, sha256_of
from scotti.models.input_checks import FrameCode, frame_codes
from scotti.models.kv_contract import (
    KV_GRAPH,
    KV_INPUT_PAST,
    KV_INPUT_VALID,
    KV_STEP_INPUTS,
    KV_STEP_OUTPUTS,
    META_KV_SLOTS,
    META_RECEPTIVE_FIELD,
    META_STEP_KIND,
    STEP_KIND_KV,
)
from scotti.models.ood import OodStats, window_reasons
from scotti.models.progress_calibration import ProgressCalibration, ProgressMapping
from scotti.models.runtime import ScottiRuntime, StepBatch, StepResult, softmax
from scotti.models.streaming import stack_frames
from scotti.models.window_checks import FrameChecks

F32 = npt.NDArray[np.float32]


class KvCache:
    """The rows of the last ``size`` frames, oldest first, as a contiguous view.

    The ring buffer of models/streaming.py's EmbeddingCache, each row (S, E), plus
    a valid flag per slot (0 until a frame has filled it), written twice the same way.
    """

    def __init__(self, size: int, slots: int, dim: int) -> None:
        if size < 1 or slots < 1 or dim < 1:
            msg = f"a key/value cache needs size, slots and dim >= 1, got {size}, {slots}, {dim}"
            raise ModelInputError(msg)
        self._size = size
        self._row = (slots, dim)
        self._buffer = np.zeros((2 * size, slots, dim), dtype=np.float32)
        self._valid = np.zeros(2 * size, dtype=np.float32)
        self._head = 0

    @property
    def size(self) -> int:
        return self._size

    def past(self) -> F32:
        """(size, S, E) view, oldest first; valid until the next push."""
        view = self._buffer[self._head : self._head + self._size]
        view.flags.writeable = False
        return view

    def valid(self) -> F32:
        """(size,) view: 1 where the slot holds a frame."""
        view = self._valid[self._head : self._head + self._size]
        view.flags.writeable = False
        return view

    def push(self, row: npt.ArrayLike) -> None:
        r = np.asarray(row, dtype=np.float32)
        if r.shape != self._row:
            msg = f"cache row must be {self._row}, got {r.shape}"
            raise ModelInputError(msg)
        for at in (self._head, self._head + self._size):
            self._buffer[at] = r
            self._valid[at] = 1.0
        self._head = (self._head + 1) % self._size

    def reset(self) -> None:
        self._buffer.fill(0.0)
        self._valid.fill(0.0)
        self._head = 0


class KvStepRuntime:
    """The streaming-native step graph in an onnxruntime CPU session."""

    def __init__(
        self, path: str | Path, threads: int = 1, *, calibrate_progress: bool = True
    ) -> None:
        """``calibrate_progress`` False: the progress head's output as it is, as in
        ``ScottiRuntime`` (what ``scotti calibrate`` fits a calibration on)."""
        self._path = Path(path)
        if threads < 1:
            msg = f"threads must be at least 1, got {threads}"
            raise ModelError(msg)
        self._threads = threads
        self._sha256 = sha256_of(self._path)
        self._session = open_session(self._path, threads)
        meta = dict(self._session.get_modelmeta().custom_metadata_map)
        try:
            graph = meta.get(c.META_GRAPH)
            if graph != KV_GRAPH or meta.get(META_STEP_KIND) != STEP_KIND_KV:
                msg = f"graph kind is {graph!r}, a key/value streaming step graph is {KV_GRAPH!r}"
                raise ModelContractError(msg)
            # The paper form's checks on everything else (version, T, frame, names).
            checked = check_metadata({**meta, c.META_GRAPH: "step"})
            _, self._window, self._embed_dim, self._card = checked
            self._slots = int(meta.get(META_KV_SLOTS, "0"))
            self._check_io()
            # A frame's row reads layers x (T-1) frames back (docs/streaming-native.md).
            layers = (self._slots - 1) // 2
            reads = self._window + layers * (self._window - 1)
            self._receptive_field = int(meta.get(META_RECEPTIVE_FIELD, str(reads)))
            self._ood = ood_stats(meta, self._embed_dim, True)
            self._progress = ProgressMapping.from_metadata(meta, switched_on=calibrate_progress)
        except (ModelContractError, ValueError) as exc:
            msg = f"{self._path.name}: {exc}"
            raise ModelContractError(msg) from None
        self._frame_shape = (c.FRAME_ROWS, 2 * c.FRAME_COLS)

    def _check_io(self) -> None:
        inputs = tuple(i.name for i in self._session.get_inputs())
        outputs = tuple(o.name for o in self._session.get_outputs())
        if inputs != KV_STEP_INPUTS or outputs != KV_STEP_OUTPUTS or self._slots < 3:
            msg = f"I/O {inputs} -> {outputs} ({self._slots} slots) is not a key/value step graph"
            raise ModelContractError(msg)
        past = self._session.get_inputs()[1].shape
        if list(past[1:]) != [self._window - 1, self._slots, self._embed_dim]:
            msg = f"past_kv is {past}, expected (B, {self._window - 1}, {self._slots}, E)"
            raise ModelContractError(msg)

    @property
    def path(self) -> Path:
        return self._path

    @property
    def sha256(self) -> str:
        return self._sha256

    @property
    def graph(self) -> str:
        """``scotti.graph``: what ``info`` and the daemon's start-up check read."""
        return KV_GRAPH

    @property
    def step_kind(self) -> str:
        return STEP_KIND_KV

    @property
    def card(self) -> dict[str, Any]:
        """The model card from metadata ``scotti.card`` ({} if the export has none)."""
        return dict(self._card)

    @property
    def window(self) -> int:
        return self._window

    @property
    def embed_dim(self) -> int:
        return self._embed_dim

    @property
    def slots(self) -> int:
        """S: vectors of E cached per frame (key and value per layer, final state)."""
        return self._slots

    @property
    def threads(self) -> int:
        return self._threads

    @property
    def receptive_field(self) -> int:
        """Frames one prediction depends on, the newest included (T + layers x (T-1))."""
        return self._receptive_field

    @property
    def frame_shape(self) -> tuple[int, int]:
        return self._frame_shape

    @property
    def ood(self) -> OodStats | None:
        return self._ood

    def ood_info(self) -> dict[str, Any]:
        """What ``info`` says about the unfamiliar score, as ``ScottiRuntime.ood_info``."""
        if self._ood is None:
            why = "the model carries no OOD statistics (export it with --calibrate)"
            return {"calibrated": False, "reason": f"not calibrated: {why}"}
        return {"calibrated": True, "threshold": self._ood.threshold, "summary": self._ood.summary}

    @property
    def progress_calibration(self) -> ProgressCalibration | None:
        """The map applied to every progress output (None: the head's output as it is)."""
        return self._progress.applied

    def progress_calibration_info(self) -> dict[str, Any]:
        """What ``info`` says about progress, as ``ScottiRuntime.progress_calibration_info``."""
        return self._progress.info()

    def run_steps(
        self, frames: npt.ArrayLike, past: npt.ArrayLike, valid: npt.ArrayLike
    ) -> StepBatch:
        """B new frames (B, H, 2W), their caches (B, T-1, S, E) and valid slots (B, T-1)
        -> one row per frame; ``embedding`` holds the new frames' cache rows (B, S, E)."""
        f = np.ascontiguousarray(frames, dtype=np.float32)
        p = np.ascontiguousarray(past, dtype=np.float32)
        v = np.ascontiguousarray(valid, dtype=np.float32)
        if f.ndim != 3 or f.shape[1:] != self._frame_shape or len(f) < 1:
            msg = f"frames must be (B, {', '.join(map(str, self._frame_shape))}), got {f.shape}"
            raise ModelInputError(msg)
        want = (len(f), self._window - 1, self._slots, self._embed_dim)
        if p.shape != want or v.shape != want[:2]:
            msg = f"past must be {want} and valid {want[:2]}, got {p.shape} and {v.shape}"
            raise ModelInputError(msg)
        feeds = {c.STEP_INPUT_FRAME: f, KV_INPUT_PAST: p, KV_INPUT_VALID: v}
        pose, logits, progress, present, pooled = self._session.run(list(KV_STEP_OUTPUTS), feeds)
        ood = self._ood
        score = ood.score(pooled, logits.argmax(axis=-1)) if ood is not None else None
        progress = self._progress(progress, logits)
        threshold = ood.threshold if ood is not None else None
        return StepBatch(pose, logits, softmax(logits), progress, present, pooled, score, threshold)

    def __repr__(self) -> str:
        return f"KvStepRuntime({str(self._path)!r}, T={self._window}, S={self._slots})"


class KvStreamingWindow:
    """Frames in, one prediction per frame once T frames have been seen (as StreamingWindow)."""

    def __init__(self, runtime: KvStepRuntime) -> None:
        self._runtime = runtime
        self._cache = KvCache(runtime.window - 1, runtime.slots, runtime.embed_dim)
        self._checks = FrameChecks(runtime.window)
        self._seen = 0
        self.reasons: tuple[str, ...] = ()

    @property
    def runtime(self) -> KvStepRuntime:
        return self._runtime

    @property
    def needed(self) -> int:
        return self._runtime.window

    @property
    def frames_seen(self) -> int:
        return self._seen

    @property
    def warming(self) -> bool:
        return self._seen < self.needed

    def past(self) -> F32:
        return self._cache.past()

    def valid(self) -> F32:
        return self._cache.valid()

    def push(self, frame: npt.ArrayLike) -> StepResult | None:
        """One frame (H, 2W) of raw counts; a prediction once the window is full (the
        batch path with one window, as ``StreamingWindow.push``). A frame of the wrong
        shape raises ModelInputError and leaves the window as it was."""
        return push_many([self], [frame])[0]

    def reset(self) -> None:
        self._cache.reset()
        self._checks.reset()
        self._seen = 0
        self.reasons = ()

    def accept_row(self, batch: StepBatch, row: int, code: FrameCode) -> StepResult | None:
        """Row ``row`` of a step run on ``past()`` into the cache and its frame's input
        checks (``frame_codes``) into the window's, as ``StreamingWindow.accept_row``:
        no result is made for a warming window, and a warm one's flags go in as it is made."""
        self._cache.push(batch.embedding[row])
        verdict = self._checks.push_code(*code)
        self._seen += 1
        if self.warming:
            return None
        result = batch.row(row, verdict.flags)
        self.reasons = window_reasons(verdict.reasons, result.flags)
        return result


def push_many(
    windows: Sequence[KvStreamingWindow], frames: Sequence[npt.ArrayLike] | npt.NDArray[Any]
) -> list[StepResult | None]:
    """One frame into each of several windows on one runtime, in ONE step-graph call.

    As ``models.streaming.push_many``: the input checks of every frame in a few numpy
    calls (``frame_codes``), a result made only for a warm window; best fed the wire's
    uint16 counts. A frame of the wrong shape raises and leaves every window as it was."""
    if len(windows) != len(frames):
        msg = f"{len(windows)} windows but {len(frames)} frames"
        raise ModelInputError(msg)
    if not windows:
        return []
    runtime = windows[0].runtime
    if any(w.runtime is not runtime for w in windows):
        msg = "push_many needs windows on one runtime"
        raise ModelError(msg)
    stacked = stack_frames(frames, runtime.frame_shape)  # (B, H, 2W), uint16 as it came
    # The checks first, while the stacking has the frames in cache (as models/streaming.py).
    codes = frame_codes(stacked)
    # Each window's cache copied into one batch array (what np.stack does, without its
    # per-array expand_dims and concatenate: this runs on every turn of the engine).
    first = windows[0]
    past = np.empty((len(windows), *first.past().shape), dtype=np.float32)  # (B, T-1, S, E)
    valid = np.empty((len(windows), *first.valid().shape), dtype=np.float32)  # (B, T-1)
    for i, w in enumerate(windows):
        past[i] = w.past()
        valid[i] = w.valid()
    batch = runtime.run_steps(stacked, past, valid)
    return [
        w.accept_row(batch, i, code) for i, (w, code) in enumerate(zip(windows, codes, strict=True))
    ]


def open_step_model(
    path: str | Path, threads: int = 1, *, calibrate_progress: bool = True
) -> ScottiRuntime | KvStepRuntime:
    """The runtime for the step graph at ``path``, by its metadata's ``scotti.graph``:
    ``KvStepRuntime`` for the streaming-native form, ``ScottiRuntime`` otherwise. The
    paper form opens as it always did; only a graph it refuses has its metadata read.
    ``calibrate_progress`` False: either form's progress head as it is."""
    try:
        return ScottiRuntime(path, threads, calibrate_progress=calibrate_progress)
    except ModelContractError:
        meta = open_session(Path(path), 1).get_modelmeta().custom_metadata_map
        if meta.get(c.META_GRAPH) != KV_GRAPH:
            raise
    return KvStepRuntime(path, threads, calibrate_progress=calibrate_progress)


# A step graph of either form, as the daemon serves it.
StepModel = ScottiRuntime | KvStepRuntime
