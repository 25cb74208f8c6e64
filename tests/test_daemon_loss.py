"""A silent foot that comes back, and a lossy, noisy line: through the daemon, replayed.

Sessions are written as a receiver would have sent them, then replayed by a
real ``scotti-daemon`` into a real mosquitto (``replay_collect``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scotti.daemon.mqtt.schemas import Health
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.firmware_protocol.framing import encode_packet
from scotti.firmware_protocol.packets import Foot
from scotti.firmware_protocol.session import SessionHeader, SessionWriter
from scotti.models.contract import WINDOW

from tests.support.broker import payloads
from tests.support.sessions import PERIOD_NS, PERIOD_US, frame_packets, synthetic_counts
from tests.test_daemon_faults import replay_collect, states

pytestmark = [pytest.mark.mosquitto, pytest.mark.slow]


class Written:
    """Just what ``replay_collect`` needs of a session."""

    def __init__(self, path: Path) -> None:
        self.path = path


def write_session(
    path: Path,
    frames: int,
    keep: Callable[[int, Foot, int], bool] | None = None,
    corrupt: Callable[[int], bool] | None = None,
) -> tuple[Written, int, int]:
    """``keep(i, foot, packet_index) -> bool`` drops packets; ``corrupt(...) -> bool`` flips a
    bit in one. Returns the session, packets dropped and packets corrupted."""
    rng = np.random.default_rng(7)
    dropped = corrupted = 0
    n = 0
    with SessionWriter(path, SessionHeader(source="simulated", device="lossy")) as writer:
        for i in range(frames):
            t = 1_000_000_000 + i * PERIOD_NS
            for foot in (Foot.LEFT, Foot.RIGHT):
                clock = 1_000_000 + i * PERIOD_US + 7_000 * int(foot)
                for packet in frame_packets(foot, i, clock, synthetic_counts(foot, i)):
                    n += 1
                    if keep is not None and not keep(i, foot, n):
                        dropped += 1
                        continue
                    data = bytearray(encode_packet(packet))
                    if corrupt is not None and corrupt(n):
                        at = int(rng.integers(0, len(data) - 1))  # never the delimiter
                        data[at] ^= 1 << int(rng.integers(0, 8))
                        corrupted += 1
                    writer.write_packet(t, bytes(data))
                    t += 1_000_000
    return Written(path), dropped, corrupted


def test_a_silent_foot_comes_back_online_and_predictions_never_stop(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    gap = range(48, 48 + 160)  # the right insole silent for 10 s (160 frames at 16 Hz)
    frames = 48 + 160 + 64
    session, dropped, _ = write_session(
        tmp_path / "silent.scotti",
        frames,
        keep=lambda i, foot, _n: not (foot == Foot.RIGHT and i in gap),
    )
    assert dropped == 160 * 4
    msgs = replay_collect(mosquitto, session, tiny_model_path, tmp_path, "silent10")  # type: ignore[arg-type]
    st = states(msgs)
    silent = next(i for i, (s, r) in enumerate(st) if "right insole silent" in r)
    assert st[silent][0] == "degraded"
    assert any(s == "online" for s, _ in st[silent + 1 :]), st  # back, not degraded for good
    poses = payloads(msgs, "pose")
    # Not one prediction lost: every frame after the warm-up predicted, silence or not.
    assert [p["seq"] for p in poses] == list(range(WINDOW - 1, frames))
    during = [p for p in poses if gap.start + 8 < p["seq"] < gap.stop]
    assert during
    assert all("right_filled" in p["flags"] for p in during)
    after = [p for p in poses if p["seq"] > gap.stop + 2]
    assert after
    assert all(not any(f.startswith("right") for f in p["flags"]) for p in after)


def test_bursty_loss_and_corruption_are_counted_and_predictions_continue(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    # A Gilbert-Elliott channel: bad state entered with p 0.02 per packet, left with 0.3,
    # losing 80 % there: 0.02 / 0.32 * 0.8 = 5 % of packets, in bursts.
    rng = np.random.default_rng(3)
    bad = False

    def keep(_i: int, _foot: Foot, _n: int) -> bool:
        nonlocal bad
        bad = rng.random() < (0.7 if bad else 0.02)
        return not (bad and rng.random() < 0.8)

    frames = 320
    session, dropped, corrupted = write_session(
        tmp_path / "lossy.scotti", frames, keep=keep, corrupt=lambda _n: rng.random() < 0.01
    )
    packets = frames * 2 * 4
    assert 0.03 < dropped / packets < 0.08  # about 5 %
    assert corrupted > 10  # about 1 % of what got through
    msgs = replay_collect(mosquitto, session, tiny_model_path, tmp_path, "lossy")  # type: ignore[arg-type]
    poses = payloads(msgs, "pose")
    assert len(poses) > 0.8 * (frames - WINDOW)  # predictions continue
    assert any("rows_missing" in p["flags"] or "left_held" in p["flags"] for p in poses)
    health = Health.model_validate(payloads(msgs, "health")[-1])
    assert health.bad_packets >= corrupted  # every corrupted packet caught by CRC or COBS
    assembler = health.pipeline["assembler"]
    assert assembler["frames_incomplete"] > 0  # lost row blocks counted
    assert assembler["rows_missing"] > 0
