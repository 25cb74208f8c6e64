"""Many insole pairs in one scotti-daemon: real ptys, a real mosquitto, one model.

Four receivers on four pseudo-terminals behind one daemon: one is unplugged
(its pty closed) and plugged back, one sends nothing but garbage, one hears
only its left insole, and the fourth keeps publishing at its rate throughout,
on its own topics.
"""

from __future__ import annotations

import itertools
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scotti.daemon.tools.bench import board_records
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import Received, collect, payloads, start_daemon

pytestmark = [pytest.mark.mosquitto, pytest.mark.slow]


def of(msgs: list[Received], device: str, name: str) -> list[dict[str, Any]]:
    return payloads([m for m in msgs if m.topic.startswith(f"scotti/{device}/")], name)


def poses_at(msgs: list[Received], device: str) -> list[float]:
    return [m.at for m in msgs if m.topic == f"scotti/{device}/pose"]


def devices_toml(path: Path, broker: Mosquitto, ports: dict[str, Path]) -> Path:
    tables = "".join(f'\n[[devices]]\nid = "{d}"\nport = "{p}"\n' for d, p in ports.items())
    path.write_text(
        f'log_level = "info"\n[mqtt]\nbroker = "{broker.url}"\nhealth_interval_s = 0.5\n{tables}'
    )
    return path


def test_four_devices_one_unplugged_one_garbage_one_foot_silent_the_steady_keeps_its_rate(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path, board_factory: Any
) -> None:
    records = board_records(12.0)  # looped: longer than the assembler's jump-back window
    left_only = [r for k, r in enumerate(records) if k % 8 < 4]  # 4 left packets, then 4 right
    names = ("steady", "unplugged", "garbage", "onefoot")
    boards = {
        n: board_factory(left_only if n == "onefoot" else records, loop=True, link=tmp_path / n)
        for n in names
    }
    # Only noise on this line: CRCs fail, no frame is ever whole.
    boards["garbage"].line = lambda data: os.urandom(len(data))
    config = devices_toml(tmp_path / "devices.toml", mosquitto, {n: boards[n].link for n in names})
    with collect(mosquitto, "scotti/#") as got:
        daemon = start_daemon(
            ["--config", str(config), "--model", str(tiny_model_path)], tmp_path / "daemon.log"
        )
        try:
            got.wait_for(
                lambda m: len(poses_at(m, "steady")) >= 8 and len(poses_at(m, "unplugged")) >= 8,
                40,
                "poses from the two working devices",
            )
            boards["unplugged"].unplug()
            got.wait_for(
                lambda m: any(
                    "receiver disconnected" in " ".join(s["reasons"])
                    for s in of(m, "unplugged", "status")
                ),
                10,
                "the unplugged device's status",
            )
            start = time.monotonic()
            time.sleep(3.0)
            during = [t for t in poses_at(got.snapshot(), "steady") if t >= start]
            boards["unplugged"].replug()
            got.wait_for(
                lambda m: len([t for t in poses_at(m, "unplugged") if t > start + 3.0]) >= 3,
                20,
                "poses again after the replug",
            )
        finally:
            assert daemon.stop() == 0, daemon.log[-3000:]
        msgs = got.snapshot()

    # The steady device did not wait for its unplugged or garbage-fed neighbours:
    # about 16 poses a second (48 in 3 s), never a stall of half a second.
    assert len(during) >= 32, f"{len(during)} poses in 3 s"
    gaps = [b - a for a, b in itertools.pairwise(during)]
    assert max(gaps) < 0.5
    # Each device on its own topics, with its own retained info, status and health.
    for name in names:
        infos = of(msgs, name, "info")
        assert infos, name
        assert infos[-1]["device_id"] == name
        assert of(msgs, name, "health"), name
        assert of(msgs, name, "status")[-1]["state"] == "offline"  # the graceful stop
    assert not of(msgs, "garbage", "pose")  # noise never became a frame
    onefoot = [" ".join(st["reasons"]) for st in of(msgs, "onefoot", "status")]
    assert any("right insole silent" in r for r in onefoot), onefoot
    garbage_health = of(msgs, "garbage", "health")[-1]
    assert garbage_health["bad_packets"] > 0
    assert garbage_health["published"] == 0
    steady_seqs = [p["seq"] for p in of(msgs, "steady", "pose")]
    assert steady_seqs == sorted(steady_seqs)
    assert all(" " not in m.topic.split("/")[1] for m in msgs)
    assert {m.topic.split("/")[1] for m in msgs} == set(names)


def test_a_bad_devices_table_is_one_line_and_exit_78(tmp_path: Path, tiny_model_path: Path) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(
        '[[devices]]\nid = "a"\nport = "/dev/null"\n[[devices]]\nid = "a"\nport = "/dev/zero"\n'
    )
    daemon = start_daemon(
        ["--config", str(config), "--model", str(tiny_model_path)], tmp_path / "bad.log"
    )
    assert daemon.wait(30) == 78
    lines = daemon.log.strip().splitlines()
    assert len(lines) == 1, daemon.log
    assert "id 'a' given twice" in lines[0]


def replay_poses(
    broker: Mosquitto, model: Path, tmp_path: Path, replays: dict[str, Path]
) -> dict[str, dict[int, Any]]:
    """Run one daemon over ``replays`` (device id -> session) to the end: its poses by seq."""
    config = tmp_path / f"{'-'.join(replays)}.toml"
    config.write_text(
        f'[mqtt]\nbroker = "{broker.url}"\n'
        + "".join(
            f'[[devices]]\nid = "{d}"\nreplay = "{p}"\nspeed = 8\n' for d, p in replays.items()
        )
    )
    with collect(broker, "scotti/#") as got:
        daemon = start_daemon(
            ["--config", str(config), "--model", str(model)], tmp_path / f"{config.stem}.log"
        )
        assert daemon.wait(60) == 0, daemon.log[-3000:]  # every replay ended: so did it
        got.wait_for(
            lambda m: all(
                any(s["state"] == "offline" for s in of(m, d, "status")) for d in replays
            ),
            10,
            "every device offline",
        )
        msgs = got.snapshot()
    return {d: {p["seq"]: p["keypoints"] for p in of(msgs, d, "pose")} for d in replays}


def test_replays_batched_in_one_daemon_predict_what_each_predicts_alone(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    from tests.support.sessions import write_synthetic_session

    one = write_synthetic_session(tmp_path / "one.scotti", frames=80).path
    other = write_synthetic_session(tmp_path / "other.scotti", frames=80, seq_start=500).path
    together = replay_poses(mosquitto, tiny_model_path, tmp_path, {"a": one, "b": other})
    alone = replay_poses(mosquitto, tiny_model_path, tmp_path, {"solo": one})["solo"]
    a, b = together["a"], together["b"]
    assert a
    assert a.keys() == alone.keys() == b.keys()
    for seq, keypoints in a.items():  # its rows never mixed with the other device's
        np.testing.assert_allclose(keypoints, alone[seq], atol=1e-4)
    assert any(not np.allclose(a[s], b[s], atol=1e-3) for s in a)  # and they differ
