"""The bench's receiver boards: simulated people's insole frames played into ptys.

Each board plays a few seconds of a simulated person (walking, squatting,
standing between), rendered once by the simulator (``sim``) and looped, as the
radio sends them: both feet, 8-row FRAME_ROWS packets, a foot frame's packets
in one write. Boards differ: board ``k`` plays person ``k % PEOPLE`` from its
own phase of the loop, and its sequence numbers and board clock go on across
loops (no insole restart at the seam).

Cheap enough to drive 128 pairs from one thread: the packets of a frame depend
only on the person and the frame's index in that person's endless stream
(board ``k`` at tick ``t`` sends index ``t + phase_k``, with ``seq`` and clock
taken from that index), so each person's stream is encoded once, a second ahead,
and shared by every board that plays them; a tick costs two ``os.write`` per
board. Writes to a board wait for a reader on its pty (the daemon's port) and
are never blocking: what the reader has not taken is dropped and counted, as a
USB receiver drops what the host does not take.
"""

from __future__ import annotations

import contextlib
import os
import select
import termios
import threading
import time
import tty
from collections.abc import Sequence
from pathlib import Path
from typing import Final

import numpy as np
from scotti.firmware_protocol.framing import encode_packet
from scotti.firmware_protocol.packets import CLOCK_MODULUS, SEQ_MODULUS, Foot, FrameRows
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, MAX_COUNT, SAMPLE_BITS

PERIOD_NS: Final = round(1e9 / FRAME_RATE_HZ)
ROWS_PER_PACKET: Final = 8  # as the radio sends them: 4 packets per foot frame
PEOPLE: Final = 4  # simulated people the boards share
SCENE_S: Final = 20.0  # about: one person's loop (walk, squat, lunge, stands between)
_SLOTS: Final = 16  # boards' writes spread over the period in this many wake-ups
_SETTLE_S: Final = 0.1  # pyserial flushes the input on open: start a little after it
_AHEAD: Final = 16  # frames encoded at once per person (one second)
_PHASE_STEP: Final = 37  # frames between two boards of one person (prime: phases spread)


def person_counts(person: int) -> np.ndarray:
    """About ``SCENE_S`` of one simulated person, (N, 2, 32, 22) uint16, standing at
    both ends (the loop's seam is still). Person 0..3 differ in body, style and seed."""
    from scotti.sim.effects.registry import parse_effects
    from scotti.sim.foot import draw_feet
    from scotti.sim.scene import PHYSICS_OVERSAMPLE, Scene, ScriptEntry, SubjectModel, build_motion
    from scotti.sim.writer import render_counts, sim_input

    scene = Scene(
        name=f"bench-person-{person}",
        seed=1000 + person,
        subject=SubjectModel(
            height_m=1.62 + 0.06 * (person % 4),
            mass_kg=58.0 + 9.0 * (person % 5),
            style_seed=person,
        ),
        script=[
            ScriptEntry(action="walking", duration_s=6.0, stand_s=1.0),
            ScriptEntry(action="squat", reps=3, stand_s=1.0),
            ScriptEntry(action="lunge", reps=2, stand_s=1.5),
        ],
        effects=[{"name": "noise", "std_counts": 3.0}],
    )
    motion = build_motion(scene, PHYSICS_OVERSAMPLE)
    feet = draw_feet(motion.subject.foot_length, subject_seed=person, session_seed=scene.seed)
    counts = render_counts(
        sim_input(motion),
        parse_effects(scene.effects),
        seed=scene.seed,
        feet=feet,
        insole=scene.insole.resolved(),
    )
    return np.ascontiguousarray(counts, dtype=np.uint16)


def foot_frame_bytes(counts: np.ndarray, foot: Foot, seq: int, clock_us: int) -> bytes:
    """One foot frame (32, 22) as the radio sends it: 8-row packets, one write."""
    return b"".join(
        encode_packet(
            FrameRows(
                foot=foot,
                seq=seq % SEQ_MODULUS,
                board_clock_us=clock_us % CLOCK_MODULUS,
                rows=FRAME_ROWS,
                cols=FRAME_COLS,
                sample_bits=SAMPLE_BITS,
                row_start=start,
                samples=counts[start : start + ROWS_PER_PACKET],
            )
        )
        for start in range(0, FRAME_ROWS, ROWS_PER_PACKET)
    )


class PersonStream:
    """One person's endless stream of encoded frames: index ``i`` is frame ``i % N`` of
    the rendering with ``seq = i`` and clock ``i`` periods (each mod its wrap), as
    (left bytes, right bytes); encoded ``_AHEAD`` frames at a time, old ones dropped."""

    def __init__(self, counts: np.ndarray) -> None:
        self.counts = counts
        self._frames: dict[int, tuple[bytes, bytes]] = {}
        self._encoded = 0  # indices below this are (or were) encoded

    def at(self, i: int) -> tuple[bytes, bytes]:
        while i >= self._encoded:
            for j in range(self._encoded, self._encoded + _AHEAD):
                frame = self.counts[j % len(self.counts)]
                clock = j * PERIOD_NS // 1000
                self._frames[j] = (
                    foot_frame_bytes(frame[0], Foot.LEFT, j, clock),
                    foot_frame_bytes(frame[1], Foot.RIGHT, j, clock),
                )
            self._encoded += _AHEAD
        return self._frames[i]

    def forget_before(self, i: int) -> None:
        for j in [j for j in self._frames if j < i]:
            del self._frames[j]


class Pty:
    """A pseudo-terminal whose follower is reachable at ``link`` (as a serial port)."""

    def __init__(self, link: Path) -> None:
        if link.exists() and not link.is_symlink():
            msg = f"{link} exists and is not a symlink; refusing to replace it"
            raise FileExistsError(msg)
        self.link = link
        self.leader, follower = os.openpty()
        tty.setraw(follower, termios.TCSANOW)  # 8-bit clean, no echo
        os.set_blocking(self.leader, False)
        device = os.ttyname(follower)
        os.close(follower)  # an open follower would hide the reader's arrival
        with contextlib.suppress(FileNotFoundError):
            link.unlink()
        os.symlink(device, link)
        self.reader_since: float | None = None  # monotonic time a reader was first seen
        self.pending = b""  # the end of a frame the reader has not taken yet

    def close(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        with contextlib.suppress(OSError):
            os.close(self.leader)


class BoardPlayer:
    """Boards for ``links``, played by one thread at 16 Hz until ``stop``."""

    def __init__(
        self,
        links: Sequence[Path | str],
        people: Sequence[np.ndarray],
        shared_dropped: object = None,
    ) -> None:
        self.streams = [PersonStream(c) for c in people]
        self.ptys = [Pty(Path(link)) for link in links]
        n = len(self.ptys)
        self.person = [k % len(self.streams) for k in range(n)]
        self.phase = [
            (k // len(self.streams)) * _PHASE_STEP % len(people[self.person[k]]) for k in range(n)
        ]
        self.slot = [k * _SLOTS // max(1, n) for k in range(n)]  # spread over the period
        self.first_phase = [
            min((self.phase[k] for k in range(n) if self.person[k] == i), default=0)
            for i in range(len(self.streams))
        ]
        for k in range(n):  # what the first ticks need, now, not while playing
            self.streams[self.person[k]].at(self.phase[k] + _AHEAD)
        self.writes = 0
        self.dropped = 0  # foot frames dropped whole: the reader had not taken the last one
        self.shared_dropped = shared_dropped  # a multiprocessing Value kept equal to it
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="bench-boards", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        for p in self.ptys:
            p.close()

    def _run(self) -> None:
        start = time.monotonic_ns()
        by_slot = [[k for k in range(len(self.ptys)) if self.slot[k] == s] for s in range(_SLOTS)]
        tick = 0
        while not self._stop.is_set():
            self._look_for_readers()
            for s, boards in enumerate(by_slot):
                if not boards:
                    continue
                due = start + tick * PERIOD_NS + s * PERIOD_NS // _SLOTS
                wait = (due - time.monotonic_ns()) / 1e9
                if wait > 0 and self._stop.wait(wait):
                    return
                for k in boards:
                    self._send(k, tick)
            for stream, phase in zip(self.streams, self.first_phase, strict=True):
                stream.forget_before(tick + phase)
            tick += 1

    def _look_for_readers(self) -> None:
        """A reader opening a follower clears the leader's hang-up; one poll for all."""
        waiting = {p.leader: p for p in self.ptys if p.reader_since is None}
        if not waiting:
            return
        poller = select.poll()
        for fd in waiting:
            poller.register(fd, select.POLLHUP)
        hung = {fd for fd, ev in poller.poll(0) if ev & select.POLLHUP}
        now = time.monotonic()
        for fd, p in waiting.items():
            if fd not in hung:
                p.reader_since = now

    def _send(self, k: int, tick: int) -> None:
        p = self.ptys[k]
        if p.reader_since is None or time.monotonic() - p.reader_since < _SETTLE_S:
            return
        for data in self.streams[self.person[k]].at(tick + self.phase[k]):
            # What the reader did not take stays pending (packets stay whole); a frame
            # that comes while some is still pending is dropped whole, as a receiver
            # drops a transfer the host does not take.
            if p.pending and not self._write(p, p.pending):
                if not self._reader_present(p.leader):  # gone (a probe, a restart): wait
                    p.reader_since, p.pending = None, b""
                    return
                self.dropped += 1
                if self.shared_dropped is not None:
                    self.shared_dropped.value = self.dropped  # type: ignore[attr-defined]
                continue
            self._write(p, data)

    def _write(self, p: Pty, data: bytes) -> bool:
        """Writes what the pty takes of ``data``; the rest stays pending. All taken?"""
        try:
            n = os.write(p.leader, data)
        except OSError:  # full: the reader lags, or it went away
            n = 0
        self.writes += 1
        p.pending = data[n:]
        return not p.pending

    @staticmethod
    def _reader_present(fd: int) -> bool:
        poller = select.poll()
        poller.register(fd, select.POLLHUP)
        return not any(ev & select.POLLHUP for _, ev in poller.poll(0))


def render_people(boards: int) -> list[np.ndarray]:
    """The people ``boards`` boards play (``PEOPLE`` at most)."""
    return [person_counts(i) for i in range(min(PEOPLE, max(1, boards)))]


def play_boards(
    links: list[str],
    seconds: float,
    ready: object,
    stop: object,
    dropped: object = None,
    people: list[np.ndarray] | None = None,
) -> None:
    """The helper process: one board per link, until ``stop`` (multiprocessing events);
    ``dropped`` (a multiprocessing Value) counts, as they happen, the foot frames the
    readers did not take; ``people``: rendered already (None: rendered here).
    ``seconds`` is unused (each person's loop has its own length): the old signature."""
    del seconds
    people = people if people is not None else render_people(len(links))
    player = BoardPlayer(links, people, dropped)
    player.start()
    ready.set()  # type: ignore[attr-defined]
    stop.wait()  # type: ignore[attr-defined]
    player.stop()


def board_records(
    seconds: float, seed: int = 0, *, per_write: bool = False
) -> list[tuple[int, bytes]]:
    """Random frames, both feet, row blocks, as (t_ns, bytes) records for a
    ``BoardEmulator`` (the tests' and the control flood's boards; random maps fail the
    outline rule, so every pose is flagged out_of_range: not what the bench plays).

    ``per_write``: a foot frame's packets in one record (one write), as a USB
    receiver hands them over in one transfer; else one record per packet, 1 ms apart.
    """
    rng = np.random.default_rng(seed)
    records: list[tuple[int, bytes]] = []
    for i in range(round(seconds * FRAME_RATE_HZ)):
        t = i * PERIOD_NS
        for foot in (Foot.LEFT, Foot.RIGHT):
            counts = rng.integers(0, MAX_COUNT // 3, (FRAME_ROWS, FRAME_COLS), dtype=np.uint16)
            data = foot_frame_bytes(counts, foot, i, i * PERIOD_NS // 1000)
            if per_write:
                records.append((t, data))
                t += 1_000_000
                continue
            for packet in data.split(b"\x00")[:-1]:
                records.append((t, packet + b"\x00"))
                t += 1_000_000
    return records
