"""``scotti session export FILE --mcap OUT.mcap``: a session as a Foxglove/ROS 2 recording.

The session's bytes go through the daemon's own path (decode, assemble,
pair, window, the model's streaming step), as fast as the model runs, and
every prediction goes to the same Foxglove channels ``scotti-daemon
--record-mcap`` writes. Log times are the recording's own: the header's
creation time plus each frame's host time in the file (a simulated session
starts at its header's time, which may be the Unix epoch), so a 60 s session
spans 60 s in Foxglove however fast it was exported. ``latency_ms`` in the
JSON channels is the model step's time here (no broker in between). Messages
are written in log-time order, the labels among the predictions, so a reader
that streams the file front to back (no index) sees them as they happened.
An existing OUT.mcap is refused unless ``--force``.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import sys
import time
from collections.abc import AsyncGenerator
from pathlib import Path
from typing import Final, Literal

from scotti.daemon.errors import DaemonError
from scotti.daemon.frames.pipeline import Pipeline, PipelineState, Prediction
from scotti.daemon.input.sources import SourceEvent, SourceItem
from scotti.daemon.mqtt import messages
from scotti.daemon.outputs import OutputError, require
from scotti.daemon.service.counters import Counters
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.overwrite import (
    FORCE_HELP,
    REFUSED,
    OutputExistsError,
    refuse_existing,
)
from scotti.firmware_protocol.session import Session, read_session

_YIELD_EVERY: Final = 64  # records between yields to the event loop


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, metavar="FILE", help="a session file")
    parser.add_argument(
        "--mcap",
        type=Path,
        required=True,
        metavar="OUT.mcap",
        help=f"write the Foxglove channels ({REFUSED})",
    )
    parser.add_argument("--force", action="store_true", help=FORCE_HELP)
    parser.add_argument("--model", type=Path, help="ONNX step graph (default: the shipped one)")
    parser.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads")


class RecordedSource:
    """A session's packet records with the host times they were recorded at."""

    live = False  # the pipeline waits for the model instead of dropping frames

    def __init__(self, session: Session, name: str) -> None:
        self.session = session
        self.name = f"export {name}"

    async def stream(self) -> AsyncGenerator[SourceItem, None]:
        yield SourceEvent("connected", self.name)
        for i, record in enumerate(self.session.packets):
            if i % _YIELD_EVERY == 0:
                await asyncio.sleep(0)
            yield record.t_ns, record.data
        yield SourceEvent("disconnected", "end of session")


@dataclasses.dataclass
class ExportResult:
    predictions: int
    session_s: float
    seconds: float


async def export_mcap(
    session: Session, source_name: str, out: Path, model: Path | None, threads: int = 1
) -> ExportResult:
    """Replay ``session`` through the daemon's path into the MCAP file ``out``."""
    from scotti.daemon.outputs.foxglove_out import FoxgloveOutput
    from scotti.daemon.settings import default_model_path
    from scotti.models.kv_streaming import open_step_model

    runtime = open_step_model(model or default_model_path(), threads=threads)
    started = time.perf_counter()
    packets = session.packets
    # The session's first moment: a label may be stamped before the bytes of its frame.
    starts = [r.t_ns for r in packets[:1]] + [lb.t_ns for lb in session.labels]
    t0 = min(starts, default=0)
    wall0 = round(session.header.created_unix * 1e9)
    device = session.header.device or "session"  # one device: the topics carry no id
    made_by = {
        "session": source_name,
        "source": session.header.source,
        "device": session.header.device,
        "model": runtime.path.name,
        "model_sha256": runtime.sha256,
    }
    # ``run`` refused an existing file unless --force: here it is replaced.
    output = FoxgloveOutput(
        mcap=out, port=None, overwrite=True, devices=(device,), metadata=made_by
    )
    count = 0
    last_wall = wall0
    last_status: tuple[object, ...] | None = None

    # The ground truth, on the same clock as the frames, written among them in time order.
    labels = sorted(session.labels, key=lambda lb: lb.t_ns)
    next_label = 0

    def labels_until(ns: int | None) -> None:
        nonlocal next_label
        while next_label < len(labels):
            at = wall0 + (labels[next_label].t_ns - t0)
            if ns is not None and at > ns:
                return
            output.label(labels[next_label], at)
            next_label += 1

    def on_prediction(p: Prediction) -> None:
        nonlocal count, last_wall
        mono = p.last_byte_mono_ns
        last_wall = wall0 + (mono - t0)
        labels_until(last_wall)
        output.prediction(
            device,
            dataclasses.replace(p, host_wall_ns=last_wall, host_mono_ns=mono),
            p.inference_ms,
        )
        count += 1

    def on_state(state: PipelineState) -> None:
        nonlocal last_status
        key = (state.source, tuple(sorted(state.feet.items())), state.reasons)
        if key == last_status:
            return  # warming up frame by frame: not a new status (the daemon does the same)
        last_status = key
        st: Literal["online", "degraded"] = "degraded" if state.reasons else "online"
        status = messages.status(st, list(state.reasons), state)
        labels_until(last_wall)
        output.status(device, status.model_copy(update={"host_wall_ns": last_wall}))

    try:
        pipeline = Pipeline(RecordedSource(session, source_name), runtime, Counters())
        await pipeline.run(on_prediction, on_state, asyncio.Event())
        labels_until(None)  # those after the last prediction
    finally:
        await output.close()
    span = (packets[-1].t_ns - packets[0].t_ns) / 1e9 if packets else 0.0
    return ExportResult(count, span, time.perf_counter() - started)


def run(args: argparse.Namespace) -> int:
    from scotti.models.errors import ModelError

    if args.mcap.resolve() == args.file.resolve():
        return _fail("--mcap must not be the session file itself")
    try:
        refuse_existing([args.mcap], force=args.force)
        require("foxglove", "scotti session export --mcap")
        session = read_session(args.file)
        result = asyncio.run(export_mcap(session, args.file.name, args.mcap, args.model))
    except (SessionError, ModelError, OutputError, DaemonError, OutputExistsError) as exc:
        return _fail(str(exc))
    size = args.mcap.stat().st_size
    rate = result.session_s / result.seconds if result.seconds else float("inf")
    print(
        f"wrote {args.mcap}: {result.predictions} predictions over {result.session_s:.1f} s "
        f"of session, {size / 1e6:.2f} MB ({size / 1e6 / max(result.session_s / 60, 1e-9):.1f}"
        f" MB per minute) in {result.seconds:.1f} s ({rate:.0f}x real time)"
    )
    return 0


def _fail(message: str) -> int:
    print(f"scotti session export: {message}", file=sys.stderr)
    return 2
