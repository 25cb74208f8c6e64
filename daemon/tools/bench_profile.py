"""``bench --profile``: where the daemon's CPU goes, by part of the frame's path.

py-spy (``pip install py-spy``, in the ``[bench]`` extra) samples the daemon and
its workers from outside for the measured seconds (``py-spy record --format raw``,
100 samples a second; each sample pauses the daemon for a moment, so a profiled
row's latency and CPU are a little above an unprofiled one's). py-spy leaves out
threads it finds idle, and a sample whose innermost frame is a wait (select,
Condition.wait, a queue's get, an idle pool thread) is left out here too: the shares are of the
time the daemon's threads ran. A thread waiting for the GIL is not idle to
py-spy: its samples go to the frame that waits (after a socket write, say), so a
part's share can be above its CPU; the samples' total, as % of a core, is printed
beside psutil's figure in the row to show how far.

Each sample goes to the part of the innermost frame of the daemon's own path in
its stack (the model's Session.run, the inference thread's Python, decoding and
assembly, the publisher and paho, serial reads, the service's glue); a stack in
none of them is the event loop's (asyncio, selectors) or "other".
"""

from __future__ import annotations

import shutil
import subprocess
import threading
from collections import Counter
from pathlib import Path
from typing import Final

# Parts of the path, by the file of a stack frame; the innermost frame in one decides.
PARTS: Final = (
    ("model (Session.run)", ("onnxruntime",)),
    ("inference thread Python", ("daemon/inference/", "models/streaming", "models/runtime",
                                 "models/ood", "models/input_checks", "models/window")),
    ("frame path (decode, assemble, pair)", ("firmware_protocol/", "daemon/frames/",
                                             "cobs/")),
    ("publisher (payloads, paho)", ("daemon/mqtt/", "paho/", "pydantic", "msgpack",
                                    "orjson", "json/")),
    ("serial reads", ("serial_asyncio", "serial/", "daemon/input/")),
    ("service (devices, counters, health)", ("daemon/service/", "daemon/outputs/")),
)  # fmt: skip
EVENT_LOOP: Final = "event loop (asyncio, selectors)"
_LOOP_NEEDLES: Final = ("asyncio/", "selectors.py", "uvloop")
_LOOP_DISPATCH: Final = ("BaseEventLoop._run_once (", "Handle._run (")
OTHER: Final = "other"
# Innermost frames that wait rather than work (py-spy's idle test misses some).
_WAITS: Final = (
    "Selector.select (selectors.py",
    "Condition.wait (threading.py",
    "Event.wait (threading.py",
    "Queue.get (queue.py",
    "_wait_for_tstate_lock (threading.py",
    "_worker (concurrent/futures/thread.py",  # an idle pool thread: in SimpleQueue.get (C)
)
_RATE_HZ: Final = 100  # samples a second per thread
ORDER: Final = (*(name for name, _ in PARTS), EVENT_LOOP, OTHER)


def part_of_stack(frames: list[str]) -> str:
    """The part a sample's stack (outermost frame first, as py-spy writes) counts for:
    its innermost frame of a part, or the event loop's when the walk outwards reaches
    the loop's dispatch first (the service's frames below it started the loop)."""
    for frame in reversed(frames):
        for name, needles in PARTS:
            if any(n in frame for n in needles):
                return name
        if frame.startswith(_LOOP_DISPATCH):
            return EVENT_LOOP
    if any(n in frame for frame in frames for n in _LOOP_NEEDLES):
        return EVENT_LOOP
    return OTHER


def shares(raw: str) -> tuple[int, int, dict[str, float], list[tuple[str, float]]]:
    """From py-spy's raw output: samples counted, samples left out (waits), share (%)
    by part, and the innermost functions with the most samples (%)."""
    waits = 0
    by_part: Counter[str] = Counter()
    by_leaf: Counter[str] = Counter()
    for line in raw.splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        frames = [f for f in stack.split(";") if not f.startswith("process ")]
        n = int(count)
        if frames and any(w in frames[-1] for w in _WAITS):
            waits += n
            continue
        by_part[part_of_stack(frames)] += n
        if frames:
            by_leaf[frames[-1]] += n
    total = sum(by_part.values())
    if not total:
        return 0, waits, {}, []
    parts = {name: 100 * by_part[name] / total for name in ORDER}
    top = [(leaf, 100 * n / total) for leaf, n in by_leaf.most_common(8)]
    return total, waits, parts, top


class Profile:
    """py-spy on ``pid`` (and its workers) for ``seconds`` once ``measuring`` is set."""

    def __init__(self, pid: int, seconds: float, measuring: threading.Event, out: Path) -> None:
        self.pid, self.seconds, self.out = pid, seconds, out
        self._proc: subprocess.Popen[bytes] | None = None
        self._thread = threading.Thread(target=self._start, args=(measuring,), daemon=True)
        self._thread.start()

    def _start(self, measuring: threading.Event) -> None:
        measuring.wait()
        cmd = [spy_path(), "record", "-p", str(self.pid), "-d", str(max(1, round(self.seconds)))]
        cmd += ["-r", str(_RATE_HZ), "-f", "raw", "-o", str(self.out), "-s"]
        self._proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    def report(self) -> str:
        """Waits for py-spy to end; its shares as lines to print."""
        self._thread.join(5.0)
        if self._proc is None:
            return "profile: py-spy did not start (no pose was measured)"
        try:
            _, err = self._proc.communicate(timeout=self.seconds + 30)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            return "profile: py-spy did not finish"
        if not self.out.is_file():
            why = err.decode(errors="replace").strip().splitlines()
            return f"profile: py-spy wrote nothing ({why[-1] if why else 'no message'})"
        total, waits, parts, top = shares(self.out.read_text(encoding="utf-8", errors="replace"))
        busy = 100 * total / (_RATE_HZ * max(1, round(self.seconds)))
        lines = [
            f"daemon CPU by part of the path (py-spy: {total} samples of running threads, "
            f"{busy:.0f} % of a core beside the row's psutil figure; {waits} samples of "
            f"waits left out; raw samples in {self.out}):"
        ]
        lines += [f"  {name:38s} {share:5.1f} %" for name, share in parts.items()]
        lines.append("  innermost functions with the most samples:")
        lines += [f"    {share:5.1f} %  {leaf}" for leaf, share in top]
        return "\n".join(lines)


def spy_path() -> str:
    """py-spy beside this Python (a venv's bin) or on PATH; FileNotFoundError if none."""
    import sys

    beside = Path(sys.executable).with_name("py-spy")
    if beside.is_file():
        return str(beside)
    found = shutil.which("py-spy")
    if found is None:
        msg = "bench --profile needs py-spy: pip install 'scotti[bench]' (or py-spy)"
        raise FileNotFoundError(msg)
    return found
