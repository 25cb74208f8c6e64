"""Profile the daemon's event loop on a replay: where the per-frame Python goes.

Runs ``scotti-daemon --replay SESSION --speed max`` in this process against a
mosquitto of its own, under cProfile, and prints the rate (frames/s) and the
event loop thread's time by part of the path (COBS and packets, assembly and
pairing, counters, publishing, ...) in CPU seconds of that thread, plus the top
functions. cProfile sees the event loop thread only: the model runs on the
inference worker's thread and is not in these figures (the rate includes it).
A measurement, never a test.

    python -m scotti.daemon.tools.profile_replay SESSION [--top 20] [--fallback-cobs]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path
from typing import Final

from scotti.daemon.service.main import main as daemon_main
from scotti.daemon.tools.local_broker import BrokerError, Mosquitto
from scotti.firmware_protocol import cobs
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session_summary import summarize

# Parts of the path, by the file a function lives in (first match wins).
PARTS: Final = (
    ("idle (waiting for work)", ("select", "epoll", "{method 'acquire'", "threading.py")),
    ("COBS + packet decoding", ("firmware_protocol/cobs", "firmware_protocol/framing",
                                "firmware_protocol/packets", "cobs/")),
    ("assembly + pairing", ("firmware_protocol/frame_path", "firmware_protocol/assembly",
                            "firmware_protocol/pairing", "firmware_protocol/wrap",
                            "firmware_protocol/overwrite")),
    ("counters", ("daemon/service/counters", "dataclasses")),
    ("publishing (payloads, MQTT)", ("daemon/mqtt/", "pydantic", "aiomqtt", "paho", "msgpack",
                                     "orjson")),
    ("session file reading", ("firmware_protocol/session", "daemon/input/")),
    ("inference hand-off", ("daemon/frames/", "daemon/inference/", "models/streaming",
                            "models/runtime", "models/input_checks", "models/ood")),
    ("asyncio", ("asyncio",)),
)  # fmt: skip


def part_of(where: str) -> str:
    for name, needles in PARTS:
        if any(n in where for n in needles):
            return name
    return "other"


def frames_in(session: Path) -> int:
    """Paired frames in the session: the foot with more frames."""
    return max(foot.frames for foot in summarize(session).feet.values())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.daemon.tools.profile_replay")
    parser.add_argument("session", type=Path, help="session file to replay")
    parser.add_argument("--model", type=Path, help="step graph (default: the shipped one)")
    parser.add_argument("--format", default="json", help="json or msgpack")
    parser.add_argument("--top", type=int, default=15, help="functions to list")
    parser.add_argument(
        "--fallback-cobs",
        action="store_true",
        help="decode COBS with the fallback decoder even if the compiled one is installed "
        "(what a host without the [fast] extra runs)",
    )
    args = parser.parse_args(argv)
    compiled = cobs._compiled
    if args.fallback_cobs:
        cobs._compiled = None  # a measurement of the fallback (put back at the end)
    try:
        return _run(args)
    finally:
        cobs._compiled = compiled


def _run(args: argparse.Namespace) -> int:
    which = "compiled (cobs package)" if cobs._compiled else "fallback (Python and numpy)"
    print(f"COBS decoder: {which}")
    if not args.session.is_file():
        print(f"profile_replay: no such session file: {args.session}", file=sys.stderr)
        return 2
    try:
        broker = Mosquitto()
        broker.start()
    except BrokerError as exc:
        print(f"profile_replay: {exc}", file=sys.stderr)
        return 2
    daemon_args = ["--replay", str(args.session), "--speed", "max", "--broker", broker.url]
    daemon_args += ["--device-id", "profile", "--format", args.format, "--log-level", "warning"]
    if args.model is not None:
        daemon_args += ["--model", str(args.model)]
    try:
        frames = frames_in(args.session)
    except SessionError as exc:
        print(f"profile_replay: {exc}", file=sys.stderr)
        broker.close()
        return 2
    # CPU time of this thread, not wall time: waits for the GIL (held by the inference
    # worker) would otherwise be charged to whatever function was running.
    profile = cProfile.Profile(time.thread_time)
    try:
        started = time.perf_counter()
        status = daemon_main(daemon_args)  # once as it runs, for the rate
        seconds = time.perf_counter() - started
        if status == 0:
            status = profile.runcall(daemon_main, daemon_args)  # once under the profiler
    finally:
        broker.close()
    print(
        f"replay at --speed max: {frames} paired frames in {seconds:.2f} s, "
        f"{frames / seconds:.0f} frames/s (without the profiler)"
    )
    report(pstats.Stats(profile), args.top)
    return status


def report(stats: pstats.Stats, top: int) -> None:
    # {(file, line, name): (cc, nc, tottime, cumtime, {caller: (nc, cc, tottime, cumtime)})}
    rows = stats.stats  # type: ignore[attr-defined]
    by_part: dict[str, float] = {}
    for (file, _line, name), (_cc, _nc, tottime, _ct, callers) in rows.items():
        if file == "~" and "poll" not in name and "acquire" not in name and callers:
            # A builtin (bytearray.append, numpy.zeros, ...) counts for whoever called it.
            for caller, (_n, _c, share, _t) in callers.items():
                part = part_of(f"{caller[0]}:{caller[2]}")
                by_part[part] = by_part.get(part, 0.0) + share
            continue
        part = part_of(f"{file}:{name}")
        by_part[part] = by_part.get(part, 0.0) + tottime
    busy = sum(t for name, t in by_part.items() if name != PARTS[0][0])
    print(f"event loop thread CPU {busy:.2f} s (idle excluded), by part of the path:")
    for name, t in sorted(by_part.items(), key=lambda kv: -kv[1]):
        if name != PARTS[0][0]:
            print(f"  {name:30s} {t:7.3f} s  {100 * t / busy:5.1f} %")
    print(f"top {top} functions by own time:")
    stats.sort_stats("tottime").print_stats(top)


if __name__ == "__main__":
    sys.exit(main())
