"""One frame's way through the daemon: source -> record -> the frame path (decode,
assemble, pair: ``firmware_protocol.frame_path``) -> window/inference -> ``on_prediction``.

Everything here runs on the event loop except the model, which runs on the
inference worker's thread. Nothing on this path blocks: a live source is
never made to wait (frames inference cannot keep up with are dropped,
counted, and the window restarts); a replay is made to wait instead, so the
same session always gives the same predictions.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final, Literal, TypeVar

import numpy as np
import numpy.typing as npt
from scotti.daemon.inference.engine import (
    InferenceEngine,
    InferenceJob,
    InferenceLane,
    InferenceResult,
    InferenceWorker,
)
from scotti.daemon.inference.published import publish
from scotti.daemon.inference.repetitions import RepetitionCounter
from scotti.daemon.inference.window import Window
from scotti.daemon.input.recording import Recorder
from scotti.daemon.input.sources import Source, SourceEvent
from scotti.daemon.service.counters import Counters
from scotti.firmware_protocol.frame_path import FramePath, FrameWatch
from scotti.firmware_protocol.packets import BoardStatus
from scotti.firmware_protocol.pairing import PairedFrame, PairingConfig
from scotti.models.contract import FRAME_RATE_HZ
from scotti.models.kv_streaming import StepModel

log = logging.getLogger(__name__)

FRAME_PERIOD_NS: Final = round(1e9 / FRAME_RATE_HZ)
T = TypeVar("T")


@dataclass(frozen=True, eq=False)
class Prediction:
    seq: int  # host-side count of paired frames since start (continuous)
    left_seq: int  # device u16 seqs of the newest pair (-1: that foot never seen)
    right_seq: int
    device_clock_us: int  # left board clock of the newest frame (right's if no left)
    host_wall_ns: int  # when the prediction was made
    host_mono_ns: int
    predicted_for_mono_ns: int  # newest frame's time + 1/16 s: the model looks one ahead
    last_byte_mono_ns: int  # last byte of the newest frame
    pose: npt.NDArray[np.float32]  # (19, 3) metres, pose frame
    action_probs: npt.NDArray[np.float32]  # (NUM_ACTIONS,)
    action: int  # index into ACTIONS; NO_ACTION when withheld (see ``withheld``)
    progress: float  # 0..1, NaN when the action has none (standing) or is withheld
    repetition: int  # repetitions completed in the current action, -1: none (standing)
    flags: tuple[str, ...]  # "left_held", "right_filled", "rows_missing", "unloaded", ...
    inference_ms: float
    # (H, 2W) uint16: the model input that made this prediction (the window's newest
    # frame, left columns then right). A read-only view of the paired frame, not a copy.
    counts: npt.NDArray[np.uint16]
    # Mahalanobis distance of the pooled vector from the training data (None: the
    # model is not calibrated); above the model's threshold the flags say "unfamiliar".
    unfamiliar_score: float | None = None
    # The OOD flag that withheld action, progress and repetition count (models/ood.py):
    # "unloaded", "out_of_range" or "unfamiliar"; None: a confident prediction.
    withheld: str | None = None


@dataclass(frozen=True)
class PipelineState:
    source: Literal["connected", "disconnected"]
    feet: dict[str, str] = field(default_factory=lambda: {"left": "ok", "right": "ok"})
    warming: tuple[int, int] = (0, 0)  # (frames_in_window, needed)
    reasons: tuple[str, ...] = ()  # why the output is degraded, one line each


class Pipeline:
    """Reads ``source`` until it ends or ``stop`` is set."""

    def __init__(
        self,
        source: Source,
        runtime: StepModel,
        counters: Counters,
        recorder: Recorder | None = None,
        *,
        pairing: PairingConfig | None = None,
        max_queue: int = 16,
        engine: InferenceEngine | None = None,
    ) -> None:
        self.source = source
        self.counters = counters
        self.recorder = recorder
        self.frames = FramePath(pairing, _StatusCount(counters))
        counters.pairing = self.frames.pairing.counters
        counters.decoder = self.frames.decoder.counters
        counters.assembly = self.frames.assembler.counters
        self.window = Window(runtime)
        # Many devices share one engine (one model call for all of them); alone, a
        # pipeline runs its own.
        self.worker: InferenceLane = (
            engine.lane(self.window, self._on_result, max_queue=max_queue)
            if engine is not None
            else InferenceWorker(self.window, self._on_result, max_queue=max_queue)
        )
        self.repetitions = RepetitionCounter()
        self._seq = 0
        self._connected = False
        self._disconnect_reason = "not connected yet"
        self._warming = (0, self.window.needed)
        self._warming_from_seq = 0  # results of older frames say nothing about the window now
        self._model_error: str | None = None
        self._ood_reasons: tuple[str, ...] = ()  # while the newest prediction is withheld
        self._state: PipelineState | None = None
        self._state_key: tuple[object, ...] = ()  # what _state was made of
        self._on_prediction: Callable[[Prediction], None] = lambda _: None
        self._on_state: Callable[[PipelineState], None] = lambda _: None

    async def run(
        self,
        on_prediction: Callable[[Prediction], None],
        on_state: Callable[[PipelineState], None],
        stop: asyncio.Event,
    ) -> None:
        self._on_prediction, self._on_state = on_prediction, on_state
        self.worker.start()
        self._update_state()
        consume = asyncio.create_task(self._consume(), name="pipeline-consume")
        stopper = asyncio.create_task(stop.wait(), name="pipeline-stop")
        try:
            await asyncio.wait({consume, stopper}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (consume, stopper):
                task.cancel()
            await asyncio.gather(consume, stopper, return_exceptions=True)
            await self.worker.stop()
        if not consume.cancelled() and (exc := consume.exception()) is not None:
            raise exc

    # --- bytes in --------------------------------------------------------------

    async def _consume(self) -> None:
        live = self.source.live
        async with contextlib.aclosing(self.source.stream()) as items:
            async for item in items:
                if isinstance(item, SourceEvent):
                    await self._on_source_event(item)
                elif live:  # never made to wait: no coroutine per read
                    self._on_live_chunk(*item)
                else:
                    await self._on_chunk(*item)
                self._update_state()
        await self._end_of_stream()
        await self.worker.wait_below(1)  # every frame's result delivered

    async def _on_chunk(self, t_ns: int, data: bytes) -> None:
        """A replay's read: it waits while inference is behind."""
        for pair in self._pairs_of(t_ns, data):
            await self._submit(pair)

    def _on_live_chunk(self, t_ns: int, data: bytes) -> None:
        """A live source's read: never made to wait."""
        for pair in self._pairs_of(t_ns, data):
            self._submit_now(pair)

    def _pairs_of(self, t_ns: int, data: bytes) -> list[PairedFrame]:
        counters = self.counters
        counters.bytes_in += len(data)
        counters.chunks_in += 1
        if self.recorder is not None:
            self.recorder.tap(t_ns, data)
        return self.frames.feed(data, t_ns)

    async def _on_source_event(self, event: SourceEvent) -> None:
        counters = self.counters
        if event.kind == "connected":
            counters.connects += 1
            counters.reconnects = max(0, counters.connects - 1)
            self._connected = True
            self._window_empty()  # pairing was reset at any earlier cut: T new frames to go
            return
        # What arrived before the cut still goes through, and its predictions are
        # delivered before the cut is reported: no pose from before "receiver
        # disconnected" follows it. After the cut, everything is learned afresh
        # (offsets, partial packets) and the window warms up again.
        await self._end_of_stream()
        await self.worker.wait_below(1)
        if self._connected:
            counters.disconnects += 1
        self._connected = False
        self._disconnect_reason = event.reason
        self.frames.reset()

    async def _end_of_stream(self) -> None:
        for pair in self.frames.end():
            await self._submit(pair)

    async def _submit(self, pair: PairedFrame) -> None:
        if not self.source.live:
            await self.worker.wait_below(self.worker.max_queue)  # a replay can wait
        self._submit_now(pair)

    def _submit_now(self, pair: PairedFrame) -> None:
        if pair.restart:
            self._window_empty()
        self.counters.dropped_frames += self.worker.submit(InferenceJob(self._seq, pair))
        self._seq += 1
        self.counters.observe_queue(self.worker.in_flight)

    def _window_empty(self) -> None:
        """The window starts over with the next frame: say so now, not at its result
        (a replugged receiver must not read as warmed up until T new frames are in)."""
        self._warming = (0, self.window.needed)
        self._ood_reasons = ()
        self._warming_from_seq = self._seq

    # --- results out (event loop thread) ---------------------------------------------

    def _on_result(self, result: InferenceResult) -> None:
        counters = self.counters
        counters.inference_ms.add(result.inference_ms)
        counters.window_restarts = self.window.restarts
        counters.observe_queue(self.worker.in_flight)
        if result.restarted:
            self.repetitions.reset()
        output = result.output
        self._model_error = result.error
        if output is None:
            self._update_state()
            return
        if result.job.seq >= self._warming_from_seq:
            self._warming = (output.frames_in_window, output.needed)
        step = output.result
        if step is not None:
            self._ood_reasons = output.reasons
            self._predict(
                result,
                step.pose,
                step.action_probs,
                step.progress,
                step.flags,
                step.unfamiliar_score,
            )
        self._update_state()

    def _predict(
        self,
        result: InferenceResult,
        pose: npt.NDArray[np.float32],
        probs: npt.NDArray[np.float32],
        progress: float,
        model_flags: tuple[str, ...] = (),
        unfamiliar_score: float | None = None,
    ) -> None:
        pair = result.job.frame
        now_mono = time.monotonic_ns()
        last_byte = pair.last_byte_mono_ns
        action, progress, repetition, held_back = publish(
            int(np.argmax(probs)), progress, model_flags, self.repetitions
        )
        left_clock, right_clock = pair.clocks
        prediction = _frozen(Prediction, {
            "seq": result.job.seq,
            "left_seq": pair.seqs[0],
            "right_seq": pair.seqs[1],
            "device_clock_us": left_clock if left_clock >= 0 else right_clock,
            "host_wall_ns": time.time_ns(),
            "host_mono_ns": now_mono,
            "predicted_for_mono_ns": (last_byte or now_mono) + FRAME_PERIOD_NS,
            "last_byte_mono_ns": last_byte,
            "pose": pose,
            "action_probs": probs,
            "action": action,
            "progress": progress,
            "repetition": repetition,
            "flags": (*pair.flags, *model_flags),
            "inference_ms": result.inference_ms,
            "counts": _read_only(pair.counts),
            "unfamiliar_score": unfamiliar_score,
            "withheld": held_back,
        })  # fmt: skip
        self.counters.predictions += 1
        self._call(self._on_prediction, prediction)

    # --- state --------------------------------------------------------------------

    def _update_state(self) -> None:
        # Everything the state is made of: most reads change none of it, and then
        # there is nothing to build or compare.
        key = (
            self._connected,
            self._disconnect_reason,
            self.frames.pairing.silent(),
            self._warming,
            self._model_error,
            self._ood_reasons,
            None if self.recorder is None else self.recorder.failed,
        )
        if key == self._state_key:
            return
        self._state_key = key
        feet = self.frames.pairing.foot_states()
        reasons = [f"{foot} insole silent" for foot, s in feet.items() if s == "silent"]
        if not self._connected:
            reasons.insert(0, f"receiver disconnected: {self._disconnect_reason}")
        if self._model_error is not None:
            reasons.append(f"inference failed: {self._model_error}")
        if self._warming[0] >= self._warming[1]:
            reasons.extend(self._ood_reasons)  # a warming window predicts nothing yet
        if self.recorder is not None and self.recorder.failed:
            reasons.append(self.recorder.failed)
        state = PipelineState(
            source="connected" if self._connected else "disconnected",
            feet=feet,
            warming=self._warming,
            reasons=tuple(reasons),
        )
        if state != self._state:
            self._state = state
            self._call(self._on_state, state)

    def _call(self, callback: Callable[[T], None], value: T) -> None:
        try:
            callback(value)
        except Exception:  # a failing consumer never kills the reader
            self.counters.callback_errors += 1
            log.debug("pipeline callback failed", exc_info=True)


class _StatusCount(FrameWatch):
    """Board status packets counted into the daemon's counters."""

    def __init__(self, counters: Counters) -> None:
        self.counters = counters

    def status(self, status: BoardStatus) -> None:
        self.counters.board_status += 1


def _frozen(cls: type[T], fields: dict[str, object]) -> T:
    """``cls(**fields)`` for a frozen dataclass, every field given, in one step instead of
    one ``object.__setattr__`` per field (a Prediction has 18; one per frame per pair)."""
    made = object.__new__(cls)
    object.__setattr__(made, "__dict__", fields)
    return made


def _read_only(array: npt.NDArray[np.uint16]) -> npt.NDArray[np.uint16]:
    """A view that cannot be written through: consumers share the frame, never copy it."""
    view = array.view()
    view.flags.writeable = False
    return view
