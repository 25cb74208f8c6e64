"""``scotti board SESSION --link PATH``: play a session as a receiver board on a pty.

Signals: SIGUSR1 unplugs the board (the link disappears), SIGUSR2 plugs it
back in (a new pty behind the same link), SIGINT/SIGTERM stop it and remove
the link. Without ``--loop`` it exits once the reader has taken the last byte.
"""

from __future__ import annotations

import argparse
import queue
import signal
import sys
from pathlib import Path
from types import FrameType

from scotti.daemon.input.board_emulator import BoardEmulator, EmulatorError
from scotti.daemon.input.speed import parse_speed


def _speed(text: str) -> float | str:
    try:
        return parse_speed(text)
    except ValueError:
        msg = f"invalid speed {text!r}: a positive number or 'max'"
        raise argparse.ArgumentTypeError(msg) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", type=Path, help="session file whose packets to play")
    parser.add_argument(
        "--link", type=Path, required=True, help="symlink to create to the pty (e.g. /tmp/scotti)"
    )
    parser.add_argument(
        "--speed", type=_speed, default=1.0, help="1 = recorded pace, N times faster, or max"
    )
    parser.add_argument(
        "--loop",
        action="store_true",
        help="start over at the end; the frame sequence numbers and board clock go on "
        "across loops (one long session), unless --repeat-numbers",
    )
    parser.add_argument(
        "--repeat-numbers",
        action="store_true",
        help="with --loop: send each loop as recorded, the numbers jumping back as after "
        "a board reset",
    )
    parser.add_argument(
        "--drain-timeout",
        type=float,
        default=5.0,
        help="at the end, seconds to wait for the reader to take the last bytes",
    )


def run(args: argparse.Namespace) -> int:
    try:
        emulator = BoardEmulator.from_session(
            args.session,
            args.link,
            speed=args.speed,
            loop=args.loop,
            continue_numbers=not args.repeat_numbers,
        )
        emulator.start()
    except (EmulatorError, OSError) as exc:
        print(f"scotti board: {exc}", file=sys.stderr)
        return 2

    # Handlers only queue the request: the main loop below carries it out, so a
    # signal never lands in the middle of an emulator call.
    requests: queue.SimpleQueue[int] = queue.SimpleQueue()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        requests.put(signum)

    watched = (signal.SIGUSR1, signal.SIGUSR2, signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, on_signal) for s in watched}
    print(f"board: {args.link} -> {emulator.device}", file=sys.stderr, flush=True)
    try:
        while True:
            try:
                signum = requests.get(timeout=0.1)
            except queue.Empty:
                if emulator.finished.is_set():
                    emulator.wait_drained(args.drain_timeout)
                    break
                continue
            if signum == signal.SIGUSR1:
                emulator.unplug()
                print("board: unplugged", file=sys.stderr, flush=True)
            elif signum == signal.SIGUSR2:
                emulator.replug()
                print(f"board: replugged -> {emulator.device}", file=sys.stderr, flush=True)
            else:
                break
    finally:
        emulator.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)
    stats = emulator.stats
    print(
        f"board: wrote {stats.records_written} records ({stats.bytes_written} bytes), "
        f"dropped {stats.records_dropped}, loops {stats.loops_completed}",
        file=sys.stderr,
    )
    return 0
