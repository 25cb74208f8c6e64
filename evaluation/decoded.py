"""A session file read and decoded into blocks of paired frames, here or in a process.

``scotti eval`` spends about a third of a session's CPU before the model sees a
frame: reading the records, decoding, assembling and pairing (the one frame
path) is Python that holds the interpreter's lock, so threads stepping the
model cannot overlap it. ``DecodeWorker`` moves it to a process of its own:
the worker reads the file and runs the frame path, and sends the pairs in
blocks of ``BLOCK_PAIRS`` (raw counts and a few flags per pair, ~1.5 MB) while
this process steps the model on the blocks before; it decodes up to
``PREFETCH_BLOCKS`` ahead (they wait in the worker: its memory, not ours).

Either way the pairs come from one generator, ``decode_session``: the worker
only ships what it yields, so a replay with or without it sees the same pairs
(tests/test_evaluation_decoded.py compares the reports).

The worker is a fresh interpreter (``python -m scotti.evaluation.decoded``), not
a fork: this process holds onnxruntime sessions and their threads, which a fork
would copy mid-state; and not ``multiprocessing``'s spawn, which imports the
caller's main module again (a script without a ``__main__`` guard would run
twice). Messages are pickles on its stdin and stdout; its stderr is ours.
"""

from __future__ import annotations

import pickle
import queue
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Final

import numpy as np
import numpy.typing as npt
from scotti.evaluation.errors import EvaluationError
from scotti.firmware_protocol.frame_path import FramePath, PairSeq
from scotti.firmware_protocol.pairing import PairedFrame, PairingConfig
from scotti.firmware_protocol.session import LabelRecord, PacketRecord, SessionReader

# Pairs a block carries (2.8 kB of counts each): long enough that shipping a block costs
# well under 1 % of decoding it, short enough that the first reaches the model early.
BLOCK_PAIRS: Final = 512
# Blocks the worker may decode ahead of the caller: one chunk of a job's segments
# (``evaluation.segments.CHUNK_FRAMES``, 46 MB), so that it decodes the next chunk
# while the caller's threads step this one.
PREFETCH_BLOCKS: Final = 32
# A message's length, before its pickle, on the pipes to and from the worker.
_LENGTH: Final = struct.Struct("<Q")
_STOP: Final = object()  # the writer thread's last item


@dataclass(frozen=True)
class PairBlock:
    """Successive paired frames as arrays (what the replay's tracks need of a pair),
    with the label records read since the block before."""

    counts: npt.NDArray[np.uint16]  # (N, H, 2W)
    restart: npt.NDArray[np.bool_]  # the window starts over with this pair
    degraded: npt.NDArray[np.bool_]  # a foot held, filled or patched (any flag)
    ext: npt.NDArray[np.int64]  # unwrapped seq (``PairSeq``), 0 where unknown
    has_ext: npt.NDArray[np.bool_]
    labels: list[LabelRecord] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.restart)

    @classmethod
    def of(
        cls, pairs: list[PairedFrame], exts: list[int | None], labels: list[LabelRecord]
    ) -> PairBlock:
        known = [e is not None for e in exts]
        return cls(
            np.stack([p.counts for p in pairs]) if pairs else np.empty((0, 0, 0), np.uint16),
            np.array([p.restart for p in pairs], dtype=bool),
            np.array([bool(p.flags) for p in pairs], dtype=bool),
            np.array([e if e is not None else 0 for e in exts], dtype=np.int64),
            np.array(known, dtype=bool),
            labels,
        )


@dataclass(frozen=True)
class SessionEnd:
    """The last message of a session: what the frame path counted, and its cost."""

    subject: dict[str, Any] | None  # the header's subject table
    decode_errors: int
    silent_pairs: dict[str, int]  # pairs with that foot zero-filled
    labels: list[LabelRecord]  # read after the last block
    cpu_seconds: float  # the decoding's own CPU time (the worker's, when it ran there)


def decode_session(
    path: str | Path, pairing: PairingConfig | None = None, block_pairs: int | None = None
) -> Iterator[PairBlock | SessionEnd]:
    """Every pair of the session in blocks (of ``BLOCK_PAIRS`` by default), then its
    ``SessionEnd``."""
    block_pairs = BLOCK_PAIRS if block_pairs is None else block_pairs
    # This generator's own CPU: between a resumption and the next yield (the caller's
    # work in between, on the same thread when decoding here, is not the decoding's).
    spent, resumed = 0.0, time.thread_time()
    frame_path = FramePath(pairing)
    clock = PairSeq()
    silent = {"left": 0, "right": 0}
    pairs: list[PairedFrame] = []
    exts: list[int | None] = []
    labels: list[LabelRecord] = []

    def held(new: list[PairedFrame]) -> None:
        for pair in new:
            exts.append(clock.of(pair))
            for foot in silent:
                silent[foot] += f"{foot}_filled" in pair.flags
        pairs.extend(new)

    def block() -> PairBlock:
        nonlocal spent
        out = PairBlock.of(pairs, exts, labels[:])  # the block keeps its own list
        pairs.clear()
        exts.clear()
        labels.clear()
        spent += time.thread_time() - resumed
        return out

    with SessionReader(path) as reader:
        subject = reader.header.subject
        for record in reader:
            if isinstance(record, LabelRecord):
                labels.append(record)
                continue
            assert isinstance(record, PacketRecord)
            held(frame_path.feed(record.data, record.t_ns))
            if len(pairs) >= block_pairs:
                yield block()
                resumed = time.thread_time()
        held(frame_path.end())
    if pairs:
        yield block()
        resumed = time.thread_time()
    spent += time.thread_time() - resumed
    yield SessionEnd(subject, frame_path.decoder.counters.errors, silent, list(labels), spent)


@dataclass(frozen=True)
class _Failed:
    """The worker could not read the session: the error, to raise here."""

    error: BaseException


def _send(stream: IO[bytes], item: object) -> None:
    body = pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_LENGTH.pack(len(body)))
    stream.write(body)
    stream.flush()


def _receive(stream: IO[bytes]) -> Any:
    """The next message; ``EOFError`` when the other end has gone."""
    head = stream.read(_LENGTH.size)
    if len(head) < _LENGTH.size:
        raise EOFError
    (length,) = _LENGTH.unpack(head)
    body = stream.read(length)
    if len(body) < length:
        raise EOFError
    return pickle.loads(body)  # our own worker's messages


def serve(requests: IO[bytes], results: IO[bytes]) -> None:
    """The worker: the pairing config, then a path at a time in; each path's blocks and
    ``SessionEnd`` (or ``_Failed``) out; ``None`` or the end of input ends it.

    A thread writes what the decoding puts in a queue of ``PREFETCH_BLOCKS``, so the
    decoding runs that far ahead of a caller busy with the blocks before."""
    pending: queue.Queue[object] = queue.Queue(PREFETCH_BLOCKS)

    def write() -> None:
        while (item := pending.get()) is not _STOP:
            _send(results, item)

    writer = threading.Thread(target=write, name="scotti-eval-decode-writer", daemon=True)
    writer.start()
    try:
        pairing = _receive(requests)
        while (path := _receive(requests)) is not None:
            try:
                for item in decode_session(path, pairing):
                    pending.put(item)
            except Exception as exc:  # every error goes to the caller
                pending.put(_Failed(_picklable(exc)))
    except EOFError:
        pass  # the caller has gone
    finally:
        pending.put(_STOP)
        writer.join()


def _picklable(exc: Exception) -> BaseException:
    try:
        pickle.loads(pickle.dumps(exc))  # a round trip of our own error
    except Exception:  # an error that does not pickle goes as its text
        return EvaluationError(f"{type(exc).__name__}: {exc}")
    return exc


class DecodeWorker:
    """A child process (``python -m scotti.evaluation.decoded``) that decodes one
    session at a time for ``blocks``, up to ``PREFETCH_BLOCKS`` blocks ahead.

    A session whose blocks are not all taken (the replay failed) leaves the pipe
    mid-session: the worker is then stopped, and the next ``blocks`` starts another."""

    def __init__(self, pairing: PairingConfig | None = None) -> None:
        self._pairing = pairing
        self._process: subprocess.Popen[bytes] | None = None

    def start(self) -> DecodeWorker:
        """Start the process now (it imports for a few tenths of a second)."""
        if self._process is None:
            self._process = subprocess.Popen(
                [sys.executable, "-m", "scotti.evaluation.decoded"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
            )
            assert self._process.stdin is not None
            _send(self._process.stdin, self._pairing)
        return self

    def blocks(self, path: str | Path) -> Iterator[PairBlock | SessionEnd]:
        """``decode_session(path)``'s items, decoded in the worker."""
        process = self.start()._process
        assert process is not None
        assert process.stdin is not None
        assert process.stdout is not None
        finished = False
        try:
            try:
                _send(process.stdin, str(path))
            except OSError:
                raise self._ended(path) from None
            while True:
                try:
                    item = _receive(process.stdout)
                except EOFError:
                    raise self._ended(path) from None
                # The worker is back at its loop after either of these.
                finished = isinstance(item, (_Failed, SessionEnd))
                if isinstance(item, _Failed):
                    raise item.error
                yield item
                if finished:
                    return
        finally:
            if not finished:
                self.close(abandon=True)

    def _ended(self, path: str | Path) -> EvaluationError:
        self.close(abandon=True)
        return EvaluationError(
            f"the decoding process ended while reading {Path(path).name} (killed: out of "
            "memory?); --decode here reads in this process"
        )

    def close(self, *, abandon: bool = False) -> None:
        """Stop the worker: asked to end between sessions, else (``abandon``: blocks of
        a session nobody reads any more) at once."""
        process, self._process = self._process, None
        if process is None:
            return
        assert process.stdin is not None
        assert process.stdout is not None
        try:
            if not abandon:
                _send(process.stdin, None)
            process.stdin.close()
        except OSError:
            abandon = True
        if abandon:
            process.kill()
        try:
            process.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        process.stdout.close()

    def __enter__(self) -> DecodeWorker:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


if __name__ == "__main__":
    import signal

    # Ctrl-C reaches the whole process group: the caller ends this worker (its stdin
    # closes, or it is killed mid-session), without a second traceback from here.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # Through the module's own name, so that what it pickles names
    # scotti.evaluation.decoded's classes, not __main__'s.
    from scotti.evaluation import decoded

    decoded.serve(sys.stdin.buffer, sys.stdout.buffer)
