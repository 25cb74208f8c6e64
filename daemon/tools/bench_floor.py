"""What a Python daemon of this shape costs per pair before it does any work.

    python -m scotti.daemon.tools.bench_floor --pairs 1 8 32 64 128 --seconds 20

Issue 42 asks for the whole daemon's CPU per pair at most 1.5x the model's own:
everything around the model (reading, decoding, assembly, pairing, the input
checks, the unfamiliar score, the three messages) within half of what the model's
step costs. This bench measures the part of that which no Python optimisation of
ours can remove, on the same boards as ``bench`` (simulated people's frames played
into pseudo-terminals, ``bench_boards``):

- each board read through the daemon's own port (``serial_port.open_port``:
  pyserial-asyncio-fast's transport, ``await reader.read(READ_SIZE)`` in one task a board),
  or (``pyserial``) pyserial's own port, whose every read waits in ``select()``
  first, or (``raw``) with the least a Python reader can do: the port's descriptor in the
  event loop's selector and one ``os.read`` a wake-up;
- every pair-frame (eight packet delimiters: both feet's four packets) handed to
  one worker thread under a condition, as the engine's lanes are, and handed back
  to the event loop once per turn with ``call_soon_threadsafe``, as the engine does;
- a pair-frame's three MQTT packets (pre-encoded bytes of about their size) written
  to a local TCP socket, one ``send`` per wake-up, as the publisher writes.

Nothing is decoded, no model runs, nothing is checked or encoded. Its CPU per
pair-frame is the floor of the daemon's work around the model in this design
(asyncio, a serial transport, one inference thread); the table puts it beside the
model's step at the batch the engine forms (``bench_model.model_cpu_ms``) and beside
the 1.5x goal's budget for that work (half the model's cost). A measurement, never
a test; CPU is this process's ``time.process_time`` (every thread of it).
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import socket
import sys
import tempfile
import threading
import time
import tty
from collections import deque
from pathlib import Path

from scotti.daemon.input.serial_port import open_port
from scotti.daemon.input.sources import READ_SIZE
from scotti.daemon.tools.bench_boards import play_boards, render_people
from scotti.daemon.tools.bench_model import model_cpu_ms

DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "scotti-default.onnx"
DELIMITERS_PER_PAIR = 8  # both feet, four 8-row packets each (bench_boards)
MESSAGES = bytes(3 * 230)  # about a pair-frame's pose, action and progress packets
MAX_BATCH = 8  # the engine's default


class Hub:
    """The engine's hand-offs without its work: frames in under a condition, one
    ``call_soon_threadsafe`` per turn back to the loop, one socket send per wake-up."""

    def __init__(self, loop: asyncio.AbstractEventLoop, out: socket.socket) -> None:
        self.loop = loop
        self.out = out
        self.cond = threading.Condition()
        self.waiting: deque[int] = deque()
        self.delivered = 0
        self._stopping = False
        self._buffer = bytearray()
        self._flush_due = False
        self._thread = threading.Thread(target=self._run, name="floor-engine", daemon=True)
        self._thread.start()

    def submit(self, board: int) -> None:
        with self.cond:
            self.waiting.append(board)
            self.cond.notify()

    def stop(self) -> None:
        with self.cond:
            self._stopping = True
            self.cond.notify()
        self._thread.join(5.0)

    def _run(self) -> None:
        while True:
            with self.cond:
                while not self.waiting and not self._stopping:
                    self.cond.wait()
                if self._stopping:
                    return
                taken = list(self.waiting)
                self.waiting.clear()
            for first in range(0, len(taken), MAX_BATCH):
                self.loop.call_soon_threadsafe(self._deliver, len(taken[first : first + MAX_BATCH]))

    def _deliver(self, frames: int) -> None:
        if self._stopping:
            return
        self.delivered += frames
        self._buffer += MESSAGES * frames
        if not self._flush_due:
            self._flush_due = True
            self.loop.call_soon(self._flush)

    def _flush(self) -> None:
        self._flush_due = False
        if self._stopping:  # the socket may be closed already
            return
        try:
            sent = self.out.send(self._buffer)
        except BlockingIOError:
            sent = 0
        del self._buffer[:sent]


async def _read_board(link: Path, board: int, hub: Hub, own_read: bool = False) -> None:
    """The daemon's way: its port (pyserial-asyncio-fast's transport) and a StreamReader;
    ``own_read``: pyserial's own port, whose read waits in select() first (the daemon's
    before daemon/input/serial_port.py)."""
    if own_read:
        import serial_asyncio_fast

        reader, writer = await serial_asyncio_fast.open_serial_connection(
            url=str(link), baudrate=115200, exclusive=True
        )
    else:
        reader, writer = await open_port(str(link), 115200)
    delimiters = 0
    try:
        while True:
            data = await reader.read(READ_SIZE)
            if not data:
                return
            delimiters += data.count(0)
            while delimiters >= DELIMITERS_PER_PAIR:
                delimiters -= DELIMITERS_PER_PAIR
                hub.submit(board)
    finally:
        writer.close()


def _read_raw(link: Path, board: int, hub: Hub, opened: list[int]) -> None:
    """The least a Python reader can do: the port's descriptor in the loop's selector,
    one ``os.read`` a wake-up (no pyserial, no transport, no StreamReader)."""
    fd = os.open(link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    opened.append(fd)
    delimiters = 0

    def readable() -> None:
        nonlocal delimiters
        try:
            data = os.read(fd, READ_SIZE)
        except BlockingIOError:
            return
        delimiters += data.count(0)
        while delimiters >= DELIMITERS_PER_PAIR:
            delimiters -= DELIMITERS_PER_PAIR
            hub.submit(board)

    hub.loop.add_reader(fd, readable)


def _drain(port: int) -> None:
    """The broker's stand-in: reads and forgets."""
    with socket.create_connection(("127.0.0.1", port)) as conn:
        while conn.recv(1 << 16):
            pass


async def measure(
    pairs: int, seconds: float, warmup: float, reader: str = "serial"
) -> tuple[float, float]:
    """(CPU % of a core, CPU us per pair-frame) of this process over ``seconds``."""
    folder = Path(tempfile.mkdtemp(prefix="scotti-floor-"))
    links = [folder / f"tty{i:03d}" for i in range(pairs)]
    ctx = multiprocessing.get_context("spawn")
    ready, stop = ctx.Event(), ctx.Event()
    boards = ctx.Process(
        target=play_boards,
        args=([str(p) for p in links], 0.0, ready, stop, None, render_people(pairs)),
        daemon=True,
    )
    boards.start()
    listener = socket.create_server(("127.0.0.1", 0))
    drain = ctx.Process(target=_drain, args=(listener.getsockname()[1],), daemon=True)
    drain.start()
    out, _ = listener.accept()
    out.setblocking(False)
    try:
        if not ready.wait(120):
            msg = "the emulated boards did not start"
            raise RuntimeError(msg)
        hub = Hub(asyncio.get_running_loop(), out)
        opened: list[int] = []
        if reader in ("serial", "pyserial"):
            own = reader == "pyserial"
            tasks = [asyncio.create_task(_read_board(p, i, hub, own)) for i, p in enumerate(links)]
        else:
            tasks = []
            for i, link in enumerate(links):
                _read_raw(link, i, hub, opened)
        await asyncio.sleep(warmup)
        cpu0, wall0, frames0 = time.process_time(), time.monotonic(), hub.delivered
        await asyncio.sleep(seconds)
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        frames = hub.delivered - frames0
        hub.stop()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await asyncio.sleep(0.2)  # the transports close on the loop's next turns
        for fd in opened:
            hub.loop.remove_reader(fd)
            os.close(fd)
    finally:
        stop.set()
        boards.join(15)
        out.close()
        listener.close()
        drain.join(5)
    if frames < pairs * seconds * 8:  # fewer than half the frames: not the floor of 16 Hz
        msg = f"{pairs} pairs: only {frames} pair-frames in {seconds:g} s"
        raise RuntimeError(msg)
    return 100.0 * cpu / wall, 1e6 * cpu / frames


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.bench_floor")
    p.add_argument("--pairs", type=int, nargs="+", default=[1, 8, 32, 64, 128])
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--warmup", type=float, default=3.0)
    p.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    p.add_argument(
        "--readers",
        nargs="+",
        choices=["pyserial", "serial", "raw"],
        default=["serial", "raw"],
        help="serial: the daemon's port; pyserial: pyserial's own read (select() first); "
        "raw: os.read in the loop's selector",
    )
    args = p.parse_args(argv)
    if any(n < 1 for n in args.pairs) or args.seconds <= 0:
        p.error("--pairs must be >= 1 and --seconds > 0")
    if not args.model.is_file():
        p.error(f"{args.model}: no such model")
    model_ms = model_cpu_ms(args.model, sorted({min(n, MAX_BATCH) for n in args.pairs}))
    print(
        "| pairs | reader | floor CPU % of a core | floor us per pair-frame "
        "| model us per frame | 1.5x budget for the rest, us | floor / budget |"
    )
    print("|---|---|---|---|---|---|---|")
    for pairs in args.pairs:
        for reader in args.readers:
            percent, us = asyncio.run(measure(pairs, args.seconds, args.warmup, reader))
            model_us = 1e3 * model_ms[min(pairs, MAX_BATCH)]
            budget = 0.5 * model_us
            print(
                f"| {pairs} | {reader} | {percent:.1f} | {us:.0f} | {model_us:.0f} "
                f"| {budget:.0f} | {us / budget:.2f} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
