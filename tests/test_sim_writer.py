"""Session writer: exact, complete, bit-identical, and what a board would send."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from scotti.firmware_protocol.framing import encode_packet, encode_packets
from scotti.firmware_protocol.packets import (
    CLOCK_MODULUS,
    BoardStatus,
    Foot,
    FrameRows,
    InsoleStatus,
)
from scotti.models.contract import NO_ACTION
from scotti.sim.effects.schedule import build_schedule
from scotti.sim.foot import neutral_feet
from scotti.sim.insole import REALISTIC
from scotti.sim.writer import render_counts, write_session

from tests.support.sim_session import decode_session
from tests.support.sim_synthetic import jump, synthetic_input, walking

FRAMES = 40
SCENE = {"name": "synthetic-walk", "seed": 5}
SUBJECT = {"mass_kg": 70.0, "foot_length_m": 0.26}


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sim") / "clean.ses"
    write_session(path, synthetic_input(walking(FRAMES)), seed=5, scene=SCENE, subject=SUBJECT)
    return path


def test_clean_session_decodes_to_the_rendered_counts(clean: Path) -> None:
    decoded = decode_session(clean)
    assert decoded.counters.errors == 0
    assert decoded.session.header.source == "simulated"
    header = decoded.session.header
    assert header.scene == {**SCENE, "insole": REALISTIC.as_dict()}  # the sensor is recorded
    assert header.subject is not None
    assert {k: header.subject[k] for k in SUBJECT} == SUBJECT
    assert header.subject["foot"] == neutral_feet(SUBJECT["foot_length_m"]).as_dict()
    assert decoded.session.header.created_unix == 0.0
    seqs = {foot: sorted(f.seq for f in decoded.frames if f.foot == foot) for foot in Foot}
    assert seqs[Foot.LEFT] == list(range(FRAMES))
    assert seqs[Foot.RIGHT] == list(range(FRAMES))
    assert all(f.complete for f in decoded.frames)
    expected = render_counts(synthetic_input(walking(FRAMES)), seed=5)  # seed: the insole's gains
    np.testing.assert_array_equal(decoded.frame_counts(FRAMES), expected)


def test_labels_for_every_frame(clean: Path) -> None:
    labels = decode_session(clean).session.labels
    assert [label.seq for label in labels] == list(range(FRAMES))
    truth = synthetic_input(walking(FRAMES)).labels
    np.testing.assert_array_equal(labels[7].keypoints, truth.keypoints[7])
    assert labels[7].action == 7
    assert all(b.t_ns - a.t_ns == 62_500_000 for a, b in itertools.pairwise(labels))


def test_rerun_is_bit_identical_and_the_seed_matters(clean: Path, tmp_path: Path) -> None:
    again = tmp_path / "again.ses"
    write_session(again, synthetic_input(walking(FRAMES)), seed=5, scene=SCENE, subject=SUBJECT)
    assert again.read_bytes() == clean.read_bytes()
    other = tmp_path / "other.ses"
    write_session(other, synthetic_input(walking(FRAMES)), seed=6, scene=SCENE, subject=SUBJECT)
    assert other.read_bytes() != clean.read_bytes()


def test_packets_left_then_right_in_row_blocks_with_board_clocks(clean: Path) -> None:
    decoded = decode_session(clean)
    blocks = decoded.blocks
    assert len(blocks) == FRAMES * 2 * 4
    first = [(int(b.foot), b.row_start, b.row_count) for _, b in blocks[:8]]
    assert first == [(f, r, 8) for f in (0, 1) for r in (0, 8, 16, 24)]
    times = [t for t, _ in blocks]
    assert times == sorted(times)
    assert times[8] - times[0] == 62_500_000  # one frame period
    for foot in Foot:
        clocks = [b.board_clock_us for _, b in blocks if b.foot == foot and b.row_start == 0]
        steps = {(b - a) % CLOCK_MODULUS for a, b in itertools.pairwise(clocks)}
        assert steps == {62_500}


def test_board_status_once_a_second(clean: Path) -> None:
    statuses = decode_session(clean).statuses
    assert len(statuses) == FRAMES // 16
    assert statuses[1][0] - statuses[0][0] == 1_000_000_000
    status = statuses[1][1]
    assert status.left.link_up
    assert status.right.link_up
    assert status.left.packets_lost == 0
    assert status.rx_packets == 32 * 8
    assert status.uptime_s - statuses[0][1].uptime_s == 1


def test_sequence_numbers_and_clocks_wrap(tmp_path: Path) -> None:
    path = tmp_path / "wrap.ses"
    write_session(path, synthetic_input(jump(24)), seed=1, seq_start=65_530)
    seqs = [b.seq for _, b in decode_session(path).blocks if b.foot == 0 and b.row_start == 0]
    assert seqs[:8] == [65_530, 65_531, 65_532, 65_533, 65_534, 65_535, 0, 1]
    sched = build_schedule(8, 16.0, t0_ns=0, clock_start_us=(CLOCK_MODULUS - 100_000, 0))
    wrapped = sched.board_clock_us[sched.foot == 0] % CLOCK_MODULUS
    assert wrapped.max() < CLOCK_MODULUS
    assert wrapped.min() < 62_500  # crossed the wrap


def test_labels_say_no_action_when_standing(tmp_path: Path) -> None:
    path = tmp_path / "jump.ses"
    sim = synthetic_input(jump(24))
    sim.labels.action[:] = NO_ACTION
    write_session(path, sim, seed=2)
    labels = decode_session(path).session.labels
    assert {label.action for label in labels} == {NO_ACTION}


def test_batch_encoding_equals_encode_packet(clean: Path) -> None:
    blocks = [b for _, b in decode_session(clean).blocks]
    rng = np.random.default_rng(0)
    dense = rng.integers(257, 4096, (8, 22)).astype(np.uint16)  # no zero byte: 254+ runs
    dense[dense % 256 == 0] += 1
    odd: list[FrameRows | BoardStatus] = [
        FrameRows(Foot.RIGHT, 65535, CLOCK_MODULUS - 1, 32, 22, 12, 24, dense),
        FrameRows(Foot.LEFT, 0, 0, 32, 22, 12, 0, np.zeros((8, 22), np.uint16)),
        FrameRows(Foot.LEFT, 1, 2, 32, 22, 12, 31, np.full((1, 22), 4095, np.uint16)),
        BoardStatus(),
        BoardStatus(7, 1000, 2, 0, InsoleStatus(3900, 88, -60, True, 5), InsoleStatus()),
    ]
    packets: list[FrameRows | BoardStatus] = [*blocks, *odd]
    assert encode_packets(packets) == [encode_packet(p) for p in packets]
