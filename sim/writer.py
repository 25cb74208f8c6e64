"""Motion + pressure + effects -> a session file, byte for byte as a board would send it.

The file holds a header (source "simulated", the scene and the subject,
``created_unix`` 0 so reruns are bit-identical), the packet records in
host-time order (FRAME_ROWS blocks, left then right, and a BOARD_STATUS once
a second, each COBS-framed by ``encode_packet``) and a label record for every
frame seq. Everything random comes from the seed: the host clock origin, each
insole's board-clock start (a u32 in microseconds, so long sessions wrap), the
receiver's uptime, batteries and signal strengths.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
from scotti.firmware_protocol.framing import encode_packets
from scotti.firmware_protocol.packets import (
    CLOCK_MODULUS,
    SEQ_MODULUS,
    BoardStatus,
    Foot,
    FrameRows,
)
from scotti.firmware_protocol.session import LabelRecord, SessionHeader, SessionWriter
from scotti.models.contract import FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, SAMPLE_BITS
from scotti.sim import SimError
from scotti.sim.effects.base import Effect
from scotti.sim.effects.receiver import board_statuses
from scotti.sim.effects.registry import EffectPlan
from scotti.sim.effects.schedule import STATUS, PacketSchedule, build_schedule, frame_times_ns
from scotti.sim.foot import Feet
from scotti.sim.insole import REALISTIC, Insole, InsoleArray, to_uint16
from scotti.sim.loads import FootLoads, foot_loads
from scotti.sim.motion import Motion
from scotti.sim.motion import labels as motion_labels
from scotti.sim.pressure import PressureRenderer

DEVICE: Final = "scotti-sim"
CHUNK_FRAMES: Final = 1024  # frames rendered at once (64 s at 16 Hz)
_GEOMETRY: Final = (FRAME_ROWS, FRAME_COLS, SAMPLE_BITS)
_CHUNKS_KEPT: Final = 3  # rendered chunks kept while packets of older frames may still come
_BATCH: Final = 4096  # packets encoded at once


@dataclass(frozen=True)
class FrameLabels:
    """Ground truth per frame, in the pose frame (models.contract)."""

    keypoints: np.ndarray  # (N, 19, 3) metres
    action: np.ndarray  # (N,) int, NO_ACTION when none
    progress: np.ndarray  # (N,) float, NaN when no action
    rep: np.ndarray  # (N,) int, -1 when none


@dataclass(frozen=True)
class SimInput:
    """What the writer needs from a motion and its subject, at the frame rate."""

    keypoints: np.ndarray  # (N, 19, 3) world metres, z up, floor at 0
    com: np.ndarray  # (N, 3)
    rate_hz: float
    mass_kg: float
    foot_length_m: float
    labels: FrameLabels
    ground_z: np.ndarray | None = None  # (N, 2) surface under each foot, None: flat floor
    # Loads at the frame rate, sampled from loads computed at the motion's own
    # (higher) rate; None: computed here from the frame-rate keypoints.
    frame_loads: FootLoads | None = None

    def loads(self) -> FootLoads:
        if self.frame_loads is not None:
            return self.frame_loads
        return foot_loads(self.keypoints, self.com, self.rate_hz, self.mass_kg, self.ground_z)


def sim_input(motion: Motion) -> SimInput:
    """A sim-body ``Motion`` (16 Hz or an integer multiple) at the frame rate, with labels.

    The foot loads are computed at the motion's rate and then sampled at the
    frame times (``FootLoads.every``): build the motion with
    ``scene.PHYSICS_OVERSAMPLE`` for forces from 128 Hz kinematics.
    """
    step = round(motion.rate_hz / FRAME_RATE_HZ)
    if step < 1 or abs(motion.rate_hz - step * FRAME_RATE_HZ) > 1e-6:
        msg = f"motion rate {motion.rate_hz} Hz is not a multiple of {FRAME_RATE_HZ} Hz"
        raise SimError(msg)
    mass = motion.subject.mass_kg
    loads = foot_loads(motion.world, motion.com, motion.rate_hz, mass, motion.ground_z)
    if step > 1:
        motion = motion.every(step)
        loads = loads.every(step)
    lab = motion_labels(motion)
    return SimInput(
        keypoints=motion.world,
        com=motion.com,
        rate_hz=motion.rate_hz,
        mass_kg=motion.subject.mass_kg,
        foot_length_m=motion.subject.foot_length,
        labels=FrameLabels(lab.keypoints, lab.action, lab.progress, lab.repetition),
        ground_z=motion.ground_z,
        frame_loads=loads,
    )


@dataclass
class RenderReport:
    """What went into a session file."""

    path: str
    frames: int
    duration_s: float
    records: int = 0
    packet_records: int = 0
    frame_packets: int = 0
    status_packets: int = 0
    radio_lost: int = 0
    unplugged: int = 0
    bytes_written: int = 0
    effects: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class CountsStream:
    """Renders counts chunk by chunk: contact pressure, the insole, the sensor effects.

    Order, physical: pressure from the feet, each taxel's gain, the pressure
    effects (hysteresis, creep), the insole's threshold and transfer curve,
    the count effects (crosstalk, broken lines, noise).
    """

    def __init__(
        self,
        loads: FootLoads,
        renderer: PressureRenderer,
        plan: EffectPlan,
        insole: InsoleArray,
        chunk_frames: int = CHUNK_FRAMES,
    ) -> None:
        self.loads = loads
        self.renderer = renderer
        self.plan = plan
        self.insole = insole
        self.chunk_frames = chunk_frames
        self.frames = len(loads.load_n)
        self._chunks: dict[int, np.ndarray] = {}
        self._next = 0  # next chunk to render: stateful effects need them in order

    def chunk(self, index: int) -> np.ndarray:
        """(n, 2, 32, 22) uint16 counts of chunk ``index``."""
        while self._next <= index:
            self._chunks[self._next] = self._render(self._next)
            self._chunks.pop(self._next - _CHUNKS_KEPT, None)
            self._next += 1
        try:
            return self._chunks[index]
        except KeyError:
            msg = f"chunk {index} already dropped: packets more than a chunk out of order"
            raise RuntimeError(msg) from None

    def _render(self, index: int) -> np.ndarray:
        start = index * self.chunk_frames
        frames = slice(start, min(self.frames, start + self.chunk_frames))
        x = self.insole.sensed_kpa(self.renderer.kpa(self.loads, frames))
        for stage in self.plan.kpa:
            x = stage.apply(x)
        x = self.insole.counts(x)
        for stage in self.plan.counts:
            x = stage.apply(x)
        return to_uint16(x * self.renderer.mask)

    def all(self) -> np.ndarray:
        """Every frame (N, 2, 32, 22) uint16; for tests and pictures, not for hours."""
        chunks = -(-self.frames // self.chunk_frames)
        return (
            np.concatenate([self.chunk(i) for i in range(chunks)])
            if chunks
            else np.zeros((0, 2, FRAME_ROWS, FRAME_COLS), np.uint16)
        )


def session_rng(seed: int) -> np.random.Generator:
    """The writer's own stream (host origin, clocks, receiver), apart from the effects'."""
    return np.random.default_rng(np.random.SeedSequence([seed, 0x5E55]))


def plan_schedule(frames: int, rate_hz: float, seed: int, rows_per_block: int) -> PacketSchedule:
    rng = session_rng(seed)
    t0_ns = int(rng.integers(10**9, 10**13))  # host monotonic time since its boot
    clocks = rng.integers(0, CLOCK_MODULUS, 2)
    return build_schedule(
        frames,
        rate_hz,
        t0_ns=t0_ns,
        clock_start_us=(int(clocks[0]), int(clocks[1])),
        rows_per_block=rows_per_block,
    )


def render_counts(
    sim: SimInput,
    effects: Iterable[Effect] = (),
    seed: int = 0,
    *,
    feet: Feet | None = None,
    insole: Insole = REALISTIC,
) -> np.ndarray:
    """All frames' counts, (N, 2, 32, 22) uint16, as the session would carry them.

    ``feet``: shape and placement (None: a normal foot, centred); ``insole``:
    the sensor, its taxel gains drawn from ``seed``.
    """
    renderer = PressureRenderer(sim.foot_length_m, feet)
    plan = EffectPlan.build(effects, seed=seed, rate_hz=sim.rate_hz, mask=renderer.mask)
    loads = sim.loads()
    return CountsStream(loads, renderer, plan, InsoleArray(insole, seed)).all()


def write_session(
    path: str | os.PathLike[str],
    sim: SimInput,
    *,
    seed: int,
    effects: Iterable[Effect] = (),
    scene: Mapping[str, Any] | None = None,
    subject: Mapping[str, Any] | None = None,
    rows_per_block: int = 8,
    seq_start: int = 0,
    chunk_frames: int = CHUNK_FRAMES,
    feet: Feet | None = None,
    insole: Insole = REALISTIC,
) -> RenderReport:
    """Render ``sim`` into a session file at ``path``; the same inputs give the same bytes.

    The header records the insole (``scene["insole"]``, every parameter) and
    the feet (``subject["foot"]``: shape and placement).
    """
    effects = tuple(effects)
    frames = len(sim.com)
    renderer = PressureRenderer(sim.foot_length_m, feet)
    plan = EffectPlan.build(effects, seed=seed, rate_hz=sim.rate_hz, mask=renderer.mask)
    loads = sim.loads()
    stream = CountsStream(loads, renderer, plan, InsoleArray(insole, seed), chunk_frames)

    schedule = plan_schedule(frames, sim.rate_hz, seed, rows_per_block)
    nominal_t_ns = schedule.t_ns.copy()
    for apply in plan.schedule:
        apply(schedule)
    statuses = board_statuses(schedule, nominal_t_ns, plan.unplugs, session_rng(seed))

    report = RenderReport(str(path), frames, frames / sim.rate_hz)
    report.effects = [e.name for e in effects]
    report.radio_lost = int(schedule.radio_lost.sum())
    report.unplugged = int((schedule.unplugged & ~schedule.radio_lost).sum())
    kept = np.flatnonzero(schedule.keep)
    order = kept[np.argsort(schedule.t_ns[kept], kind="stable")]
    label_t: list[int] = frame_times_ns(schedule).tolist()
    line = plan.line_stages(schedule.t0_ns)

    header = SessionHeader(
        source="simulated",
        device=DEVICE,
        rows=FRAME_ROWS,
        cols=FRAME_COLS,
        sample_bits=SAMPLE_BITS,
        rate_hz=sim.rate_hz,
        created_unix=0.0,  # no wall clock in simulated files: reruns are bit-identical
        scene={**(scene or {}), "insole": insole.as_dict()},
        subject={**(subject or {}), "foot": renderer.feet.as_dict()},
    )
    emit = _Emitter(schedule, stream, statuses, seq_start)
    truth = sim.labels
    next_label = 0
    # Re-running a scene replaces its file (same inputs, same bytes): users re-run sims.
    with SessionWriter(path, header, flush_each=False, overwrite=True) as writer:
        for start in range(0, len(order), _BATCH):
            batch = order[start : start + _BATCH].tolist()
            for i, data in zip(batch, encode_packets(emit.packets(batch)), strict=True):
                t = emit.t_ns[i]
                while next_label < frames and label_t[next_label] <= t:
                    writer.write_label(_label(truth, next_label, seq_start, label_t[next_label]))
                    next_label += 1
                reads = [(t, data)]
                for stage in line:
                    reads = [r for t_in, d in reads for r in stage.process(t_in, d)]
                for t_out, d in reads:
                    writer.write_packet(t_out, d)
                    report.bytes_written += len(d)
                    report.packet_records += 1
        while next_label < frames:
            writer.write_label(_label(truth, next_label, seq_start, label_t[next_label]))
            next_label += 1
        report.records = writer.records
    report.frame_packets = emit.frame_packets
    report.status_packets = emit.status_packets
    return report


class _Emitter:
    """Builds the packet objects of schedule entries (plain lists: fast lookups)."""

    def __init__(
        self,
        schedule: PacketSchedule,
        stream: CountsStream,
        statuses: Mapping[int, BoardStatus],
        seq_start: int,
    ) -> None:
        self.t_ns: list[int] = schedule.t_ns.tolist()
        self.foot: list[int] = schedule.foot.tolist()
        self.frame: list[int] = schedule.frame.tolist()
        self.row_start: list[int] = schedule.row_start.tolist()
        self.clock: list[int] = (schedule.board_clock_us % CLOCK_MODULUS).tolist()
        self.rows_per_block = schedule.rows_per_block
        self.stream = stream
        self.statuses = statuses
        self.seq_start = seq_start
        self.frame_packets = 0
        self.status_packets = 0

    def packets(self, indices: list[int]) -> list[FrameRows | BoardStatus]:
        out: list[FrameRows | BoardStatus] = []
        cf, rpb = self.stream.chunk_frames, self.rows_per_block
        for i in indices:
            foot = self.foot[i]
            if foot == STATUS:
                out.append(self.statuses[i])
                self.status_packets += 1
                continue
            k, rs = self.frame[i], self.row_start[i]
            block = self.stream.chunk(k // cf)[k % cf, foot, rs : rs + rpb]
            seq = (self.seq_start + k) % SEQ_MODULUS
            out.append(FrameRows(Foot(foot), seq, self.clock[i], *_GEOMETRY, rs, block))
            self.frame_packets += 1
        return out


def _label(labels: FrameLabels, k: int, seq_start: int, t_ns: int) -> LabelRecord:
    return LabelRecord(
        seq=(seq_start + k) % SEQ_MODULUS,
        t_ns=t_ns,
        keypoints=labels.keypoints[k],
        action=int(labels.action[k]),
        progress=float(labels.progress[k]),
        rep=int(labels.rep[k]),
    )
