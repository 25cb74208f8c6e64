"""Left and right foot frames paired into one model input per moment (sans-I/O).

Each insole board counts its own frames (u16 seq) and keeps its own clock
(u32 us); both wrap and the two boards' seqs may be offset from each other.
Every frame is mapped to a pair index ``k`` (one per moment, 16 Hz):
``k = unwrapped seq - offset`` per foot. A foot's offset is learned when it
first appears (or after its board restarted): its frame pairs with the other
foot's newest frame if that one still waits for a partner, else with the next
moment. Pairs leave in ``k`` order, never twice.

What happens when things go wrong (each counted, each flagged on the pair):
- duplicates are dropped; a frame for a moment already sent is dropped (late);
- a frame may arrive up to ``reorder_frames`` moments out of order;
- a foot missing at a moment is waited for ``reorder_frames`` moments, then
  held (its last frame repeated, ``left_held``) for up to ``hold_s``, then
  filled with zeros (``left_filled``) and reported silent: the state degrades;
- a short gap of both feet is bridged with held frames, so the window keeps
  its 16 Hz cadence; a gap longer than ``gap_s`` starts the window over
  (``restart``) instead of pretending the frames in between happened;
- missing rows of a frame are taken from that foot's previous frame
  (``rows_missing``).

``PairedFrame.feet`` says per foot where its half came from (``WHOLE``,
``PATCHED``, ``PARTIAL``, ``HELD``, ``FILLED``): what training data needs to
know which moments are real (export/data.py).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt
from scotti.firmware_protocol.assembly import FootFrame, no_rows_missing
from scotti.firmware_protocol.packets import DEFAULT_COLS, DEFAULT_ROWS
from scotti.firmware_protocol.wrap import clock_delta_us, seq_delta

# The repair rules, the same live and in training (each equals its models.contract name):
FRAME_RATE_HZ: Final = 16.0  # the insoles' frame rate (FRAME_RATE_HZ)
HOLD_FRAMES: Final = 8  # a silent foot's last frame is repeated 0.5 s (SILENT_FOOT_HOLD_FRAMES)
RESTART_GAP_FRAMES: Final = 16  # a longer gap (1 s) restarts the window (WINDOW_RESTART_GAP_FRAMES)

LEFT: Final = 0
RIGHT: Final = 1
FOOT_NAMES: Final = ("left", "right")
_SEQ_MASK: Final = 0xFFFF
_CLOCK_MASK: Final = 0xFFFFFFFF
_RECENT: Final = 64  # seqs per foot remembered to spot duplicates

# Where a foot's half of a pair came from:
WHOLE: Final = "whole"  # its frame, every row received
PATCHED: Final = "patched"  # its frame, missing rows taken from the foot's previous frame
PARTIAL: Final = "partial"  # its frame, missing rows zero (no previous frame to take them from)
HELD: Final = "held"  # no frame: the foot's last frame repeated (up to ``hold_s``)
FILLED: Final = "filled"  # no frame: zeros (silent past ``hold_s``, or never heard)


@dataclass(frozen=True)
class PairingConfig:
    rate_hz: float = FRAME_RATE_HZ
    reorder_frames: int = 2  # moments to wait for a late or missing frame
    # a silent foot is held this long, then filled and reported silent (0.5 s)
    hold_s: float = HOLD_FRAMES / FRAME_RATE_HZ
    # a longer gap of both feet restarts the window (1 s)
    gap_s: float = RESTART_GAP_FRAMES / FRAME_RATE_HZ

    @property
    def period_us(self) -> float:
        return 1e6 / self.rate_hz

    @property
    def hold_frames(self) -> int:
        return round(self.hold_s * self.rate_hz)

    @property
    def gap_frames(self) -> int:
        return round(self.gap_s * self.rate_hz)


@dataclass(frozen=True, eq=False)
class PairedFrame:
    """One moment: both feet side by side, as the model takes it."""

    counts: npt.NDArray[np.uint16]  # (H, 2W): left columns then right columns
    seqs: tuple[int, int]  # device seqs (left, right); a held foot's expected seq; -1 unknown
    clocks: tuple[int, int]  # board clocks in us (left, right), estimated when held; -1 unknown
    last_byte_mono_ns: int  # host time of the last byte of the newest frame in the pair
    flags: tuple[str, ...] = ()
    restart: bool = False  # the window must start over with this frame
    feet: tuple[str, str] = (WHOLE, WHOLE)  # where each half came from (left, right)


@dataclass
class PairingCounters:
    frames_in: list[int] = field(default_factory=lambda: [0, 0])  # per foot
    duplicates: int = 0
    late: int = 0  # arrived after its moment was sent
    bad_geometry: int = 0  # frames whose shape is not the model's
    held: list[int] = field(default_factory=lambda: [0, 0])  # pairs with the foot held
    filled: list[int] = field(default_factory=lambda: [0, 0])  # pairs with the foot zero-filled
    rows_missing: int = 0  # frames completed from the previous frame
    gaps: int = 0  # moments bridged with both feet held
    restarts: int = 0  # long gaps: the window started over
    resyncs: int = 0  # a board's seqs jumped (restart, loop): its offset was learned again
    pairs_out: int = 0


@dataclass(slots=True)
class _Entry:
    counts: npt.NDArray[np.uint16]
    seq: int
    clock: int
    last_byte_ns: int
    rows_missing: bool
    source: str  # WHOLE, PATCHED or PARTIAL


@dataclass
class _Track:
    """What is known about one foot's board."""

    offset: int | None = None  # k = ext - offset
    ext: int = 0  # unwrapped seq of the newest frame (by seq)
    raw_seq: int = 0
    clock: int = 0
    newest_k: int | None = None
    last_counts: npt.NDArray[np.uint16] | None = None  # newest frame, to complete missing rows
    sent: _Entry | None = None  # the last frame of this foot that went out, to hold
    missed: int = 0  # consecutive pairs sent without this foot
    recent: deque[int] = field(default_factory=lambda: deque(maxlen=_RECENT))


class Pairing:
    """``push(FootFrame) -> [PairedFrame]``; ``flush()`` at the end of a stream."""

    def __init__(self, config: PairingConfig | None = None) -> None:
        self.config = config if config is not None else PairingConfig()
        self._hold_frames = self.config.hold_frames  # the config is frozen: worked out once
        self._gap_frames = self.config.gap_frames
        self.counters = PairingCounters()
        self._tracks = (_Track(), _Track())
        self._pending: dict[int, dict[int, _Entry]] = {}
        self._next_k: int | None = None
        self._restart_next = False
        self._last_arrival_ns = 0

    # --- public --------------------------------------------------------------

    def silent(self) -> tuple[bool, bool]:
        """(left, right): held longer than ``hold_s`` (``foot_states`` in two booleans)."""
        hold = self._hold_frames
        left, right = self._tracks
        return (left.missed > hold, right.missed > hold)

    def foot_states(self) -> dict[str, str]:
        """{"left": "ok"|"silent", "right": ...}: silent once held longer than ``hold_s``."""
        return {
            FOOT_NAMES[f]: "silent" if t.missed > self.config.hold_frames else "ok"
            for f, t in enumerate(self._tracks)
        }

    def reset(self) -> None:
        """Forget everything (the source reconnected): offsets are learned again."""
        self._tracks = (_Track(), _Track())
        self._pending.clear()
        self._next_k = None
        self._restart_next = True

    def push(self, frame: FootFrame) -> list[PairedFrame]:
        foot = int(frame.foot)
        if foot not in (LEFT, RIGHT) or frame.counts.shape != (DEFAULT_ROWS, DEFAULT_COLS):
            self.counters.bad_geometry += 1
            return []
        self.counters.frames_in[foot] += 1
        out: list[PairedFrame] = []
        k = self._place(foot, frame)
        track = self._tracks[foot]
        # Every k in ``recent`` is at most ``newest_k``: a newer k needs no look.
        if track.newest_k is not None and k <= track.newest_k and k in track.recent:
            self.counters.duplicates += 1
            return out
        if self._next_k is None:
            self._next_k = k
        if k < self._next_k:
            self.counters.late += 1
            track.missed = 0  # too late to use, but the foot is back: wait for its next frame
            return out
        if k - (self._next_k - 1) > self._gap_frames:
            out += self._send_pending()  # what came before the gap still goes out
            self._next_k = k
            self._restart_next = True
            self.counters.restarts += 1
        track.recent.append(k)
        entry = self._entry(track, frame)
        self._pending.setdefault(k, {})[foot] = entry
        if track.newest_k is None or k > track.newest_k:
            track.newest_k = k
        self._last_arrival_ns = frame.last_byte_ns
        out += self._drain()
        return out

    def flush(self) -> list[PairedFrame]:
        """Send every pending moment (end of a replay), holding what is missing."""
        return self._send_pending()

    # --- placing a frame -----------------------------------------------------

    def _place(self, foot: int, frame: FootFrame) -> int:
        """The pair index of ``frame``; learns the foot's offset when needed."""
        track = self._tracks[foot]
        if track.offset is None:
            return self._learn(foot, frame)
        d = seq_delta(frame.seq, track.raw_seq)
        # A step back (late frame) or a long step forward (gap) must agree with the
        # board's clock; if it does not, the board restarted. No frame is a second
        # late: a longer step back is a restart (or a replay that looped) whatever the clock.
        gap = self._gap_frames
        if d < -gap or ((d < 0 or d > gap) and not self._clock_agrees(track, frame, d)):
            self.counters.resyncs += 1
            return self._learn(foot, frame)
        if d > 0:
            track.ext += d
            track.raw_seq, track.clock = frame.seq, frame.board_clock_us
            return track.ext - track.offset
        return track.ext + d - track.offset

    def _clock_agrees(self, track: _Track, frame: FootFrame, d: int) -> bool:
        """Did the board's clock run as long as its seq says? (No: it restarted.)"""
        elapsed = clock_delta_us(frame.board_clock_us, track.clock)
        expected = d * self.config.period_us
        return abs(elapsed - expected) <= 0.2 * abs(expected)

    def _learn(self, foot: int, frame: FootFrame) -> int:
        track, other = self._tracks[foot], self._tracks[1 - foot]
        next_k = self._next_k
        other_active = (
            other.newest_k is not None
            and other.missed == 0
            and (next_k is None or other.newest_k >= next_k - 1 - self.config.reorder_frames)
        )
        if other_active:
            assert other.newest_k is not None
            waiting = self._pending.get(other.newest_k, {})
            k = other.newest_k if (waiting and foot not in waiting) else other.newest_k + 1
        else:
            k = 0 if next_k is None else next_k
            gap_ns = frame.last_byte_ns - self._last_arrival_ns
            if next_k is not None and self._last_arrival_ns and gap_ns > self.config.gap_s * 1e9:
                k = next_k + self.config.gap_frames + 1  # nothing to align to: go by host time
        track.recent.clear()
        track.ext, track.raw_seq, track.clock = frame.seq, frame.seq, frame.board_clock_us
        track.offset = frame.seq - k
        return k

    def _entry(self, track: _Track, frame: FootFrame) -> _Entry:
        counts = np.asarray(frame.counts, dtype=np.uint16)
        has_missing = not no_rows_missing(frame)
        source = WHOLE
        if has_missing:
            missing = np.asarray(frame.rows_missing, dtype=bool)
            counts = counts.copy()
            if track.last_counts is None:
                counts[missing], source = 0, PARTIAL
            else:
                counts[missing], source = track.last_counts[missing], PATCHED
            self.counters.rows_missing += 1
        track.last_counts = counts
        return _Entry(
            counts, frame.seq, frame.board_clock_us, frame.last_byte_ns, has_missing, source
        )

    # --- sending pairs -------------------------------------------------------

    def _drain(self) -> list[PairedFrame]:
        out: list[PairedFrame] = []
        reorder = self.config.reorder_frames
        pending = self._pending
        left, right = self._tracks
        while self._next_k is not None and pending:
            k = self._next_k
            entry = pending.get(k)
            if entry is not None and len(entry) == 2:
                out.append(self._send(k))
                continue
            newest = max(t.newest_k for t in (left, right) if t.newest_k is not None)
            if newest - k >= reorder or self._other_known_silent(entry or {}):
                out.append(self._send(k))
            else:
                break
        return out

    def _other_known_silent(self, entry: dict[int, _Entry]) -> bool:
        """One foot is here and has been all along, the other is already being held."""
        if len(entry) != 1:
            return False
        present = next(iter(entry))
        return self._tracks[present].missed == 0 and self._tracks[1 - present].missed > 0

    def _send_pending(self) -> list[PairedFrame]:
        out: list[PairedFrame] = []
        while self._next_k is not None and self._pending:
            out.append(self._send(self._next_k))
        return out

    def _send(self, k: int) -> PairedFrame:
        entry = self._pending.pop(k, {})
        if len(entry) == 2:
            return self._send_both(k, entry[LEFT], entry[RIGHT])
        if not entry:
            self.counters.gaps += 1
        self._next_k = k + 1
        halves: list[npt.NDArray[np.uint16]] = []
        seqs: list[int] = []
        clocks: list[int] = []
        flags: list[str] = []
        feet: list[str] = []
        last_byte = 0
        for foot, track in enumerate(self._tracks):
            got = entry.get(foot)
            name = FOOT_NAMES[foot]
            if got is not None:
                track.missed = 0
                track.sent = got
                halves.append(got.counts)
                seqs.append(got.seq)
                clocks.append(got.clock)
                last_byte = max(last_byte, got.last_byte_ns)
                feet.append(got.source)
                if got.rows_missing:
                    flags.append("rows_missing")
                continue
            track.missed += 1
            held = track.sent
            if held is not None and track.missed <= self.config.hold_frames:
                halves.append(held.counts)
                flags.append(f"{name}_held")
                feet.append(HELD)
                self.counters.held[foot] += 1
            else:
                halves.append(np.zeros((DEFAULT_ROWS, DEFAULT_COLS), dtype=np.uint16))
                flags.append(f"{name}_filled")
                feet.append(FILLED)
                self.counters.filled[foot] += 1
            seqs.append(-1 if track.offset is None else (k + track.offset) & _SEQ_MASK)
            step = round(track.missed * self.config.period_us)
            clocks.append(-1 if held is None else (held.clock + step) & _CLOCK_MASK)
        restart, self._restart_next = self._restart_next, False
        self.counters.pairs_out += 1
        return _paired(
            np.concatenate(halves, axis=1),
            (seqs[LEFT], seqs[RIGHT]),
            (clocks[LEFT], clocks[RIGHT]),
            last_byte,
            tuple(dict.fromkeys(flags)),
            restart,
            (feet[LEFT], feet[RIGHT]),
        )

    def _send_both(self, k: int, left: _Entry, right: _Entry) -> PairedFrame:
        """``_send`` of a moment with both feet's frames: the usual one, in fewer steps."""
        self._next_k = k + 1
        track_left, track_right = self._tracks
        track_left.missed = track_right.missed = 0
        track_left.sent, track_right.sent = left, right
        restart, self._restart_next = self._restart_next, False
        self.counters.pairs_out += 1
        return _paired(
            np.concatenate((left.counts, right.counts), axis=1),
            (left.seq, right.seq),
            (left.clock, right.clock),
            max(0, left.last_byte_ns, right.last_byte_ns),
            _ROWS_MISSING if left.rows_missing or right.rows_missing else (),
            restart,
            (left.source, right.source),
        )


_ROWS_MISSING: Final = ("rows_missing",)


def _paired(
    counts: npt.NDArray[np.uint16],
    seqs: tuple[int, int],
    clocks: tuple[int, int],
    last_byte_mono_ns: int,
    flags: tuple[str, ...],
    restart: bool,
    feet: tuple[str, str],
) -> PairedFrame:
    """``PairedFrame(...)`` without the frozen dataclass's one ``object.__setattr__`` per
    field: one per moment."""
    pair = object.__new__(PairedFrame)
    object.__setattr__(pair, "__dict__", {
        "counts": counts, "seqs": seqs, "clocks": clocks,
        "last_byte_mono_ns": last_byte_mono_ns, "flags": flags, "restart": restart,
        "feet": feet,
    })  # fmt: skip
    return pair
