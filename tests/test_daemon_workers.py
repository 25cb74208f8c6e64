"""``processes = N``: the devices shared among worker processes (daemon/service/processes.py).

Real ptys, a real mosquitto, real worker processes: a worker killed with
SIGKILL (as the OOM killer does) is started again and its device comes back,
while the device of the other worker keeps its rate throughout.
"""

from __future__ import annotations

import itertools
import json
import os
import pickle
import re
import signal
import socket
import struct
import time
from pathlib import Path
from typing import Any

import pytest
from scotti.daemon.service.processes import share_devices, worker_settings
from scotti.daemon.settings import ConfigError, DeviceSettings, load_settings
from scotti.daemon.tools.bench import board_records
from scotti.daemon.tools.local_broker import Mosquitto

from tests.support.broker import Received, collect, payloads, start_daemon
from tests.support.export_sessions import write_session


def _devices(n: int) -> tuple[DeviceSettings, ...]:
    return tuple(DeviceSettings(id=f"d{i}", port=f"/dev/ttyACM{i}") for i in range(n))


def test_every_nth_device_goes_to_each_worker_and_none_is_empty() -> None:
    shares = share_devices(_devices(5), 2)
    assert [[d.id for d in s] for s in shares] == [["d0", "d2", "d4"], ["d1", "d3"]]
    assert len(share_devices(_devices(2), 8)) == 2  # never a worker without a device
    assert [len(s) for s in share_devices(_devices(3), 1)] == [3]


def test_a_worker_s_settings_pickle_and_keep_everything_but_the_other_devices(
    tmp_path: Path,
) -> None:
    config = tmp_path / "d.toml"
    tables = "".join(f'[[devices]]\nid = "d{i}"\nport = "/dev/ttyACM{i}"\n' for i in range(3))
    config.write_text(f'processes = 2\n[mqtt]\nbroker = "mqtt://broker:1884"\n{tables}')
    settings = load_settings({}, config)  # a class made for this file: it does not pickle
    share = share_devices(settings.device_list(), settings.processes)[1]
    worker = pickle.loads(pickle.dumps(worker_settings(settings, share)))
    assert [d.id for d in worker.device_list()] == ["d1"]
    assert worker.processes == 1
    assert worker.mqtt.broker == "mqtt://broker:1884"
    assert worker.mqtt_for(share[0]).device_id == "d1"


def test_processes_with_an_output_is_a_config_error() -> None:
    devices = [{"id": "a", "port": "/dev/a"}, {"id": "b", "port": "/dev/b"}]
    with pytest.raises(ConfigError, match="processes"):
        load_settings({"processes": 2, "devices": devices, "outputs": {"web": 0}})
    load_settings({"processes": 2, "devices": devices})  # without: fine


def _poses_at(msgs: list[Received], device: str) -> list[float]:
    return [m.at for m in msgs if m.topic == f"scotti/{device}/pose"]


def _statuses(msgs: list[Received], device: str) -> list[dict[str, Any]]:
    return payloads([m for m in msgs if m.topic.startswith(f"scotti/{device}/")], "status")


@pytest.mark.mosquitto
@pytest.mark.slow
def test_a_killed_worker_comes_back_and_the_other_keeps_its_rate(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path, board_factory: Any
) -> None:
    records = board_records(12.0)
    names = ("steady", "victim", "third")  # worker 0: steady, third; worker 1: victim
    boards = {n: board_factory(records, loop=True, link=tmp_path / n) for n in names}
    tables = "".join(f'\n[[devices]]\nid = "{n}"\nport = "{boards[n].link}"\n' for n in names)
    config = tmp_path / "workers.toml"
    config.write_text(
        f'log_level = "info"\nprocesses = 2\n[mqtt]\nbroker = "{mosquitto.url}"\n'
        f"health_interval_s = 0.5\n{tables}"
    )
    with collect(mosquitto, "scotti/#") as got:
        daemon = start_daemon(
            ["--config", str(config), "--model", str(tiny_model_path)], tmp_path / "daemon.log"
        )
        try:
            got.wait_for(
                lambda m: all(len(_poses_at(m, n)) >= 8 for n in names), 60, "poses from all three"
            )
            found = re.search(r"worker 1 \(pid (\d+)\): victim", daemon.log)
            assert found, daemon.log[-3000:]
            victim_pid = int(found.group(1))
            assert victim_pid != daemon.proc.pid
            start = time.monotonic()
            os.kill(victim_pid, signal.SIGKILL)
            # The broker says so for it (its client's last will), then it is back.
            got.wait_for(
                lambda m: any(
                    x.at > start and json.loads(x.payload)["state"] == "offline"
                    for x in m
                    if x.topic == "scotti/victim/status"
                ),
                20,
                "the killed worker's device offline",
            )
            got.wait_for(
                lambda m: len([t for t in _poses_at(m, "victim") if t > start + 1.0]) >= 8,
                60,
                "poses from the restarted worker",
            )
            steady = [t for t in _poses_at(got.snapshot(), "steady") if t >= start]
        finally:
            assert daemon.stop() == 0, daemon.log[-3000:]
        msgs = got.snapshot()

    assert "worker 1 (victim) died (signal SIGKILL)" in daemon.log
    pids = re.findall(r"worker 1 \(pid (\d+)\): victim", daemon.log)
    assert pids[0] == str(victim_pid)
    assert len(set(pids)) == len(pids) == 2, pids  # started again, as a new process
    # The other worker's device never waited for the killed one: its rate throughout.
    span = steady[-1] - steady[0]
    assert len(steady) >= 14 * span, f"{len(steady)} poses in {span:.1f} s"
    assert max(b - a for a, b in itertools.pairwise(steady)) < 0.5
    for name in names:  # every worker stopped gracefully: each device says offline last
        assert _statuses(msgs, name)[-1]["state"] == "offline", name


def test_a_model_that_does_not_load_stops_every_worker_with_78(tmp_path: Path) -> None:
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    tables = "".join(f'\n[[devices]]\nid = "d{i}"\nport = "/dev/null{i}"\n' for i in range(2))
    config = tmp_path / "bad.toml"
    config.write_text(f'processes = 2\n[mqtt]\nbroker = "mqtt://127.0.0.1:1"\n{tables}')
    daemon = start_daemon(["--config", str(config), "--model", str(bad)], tmp_path / "bad.log")
    assert daemon.wait(60) == 78
    assert "model error" in daemon.log
    assert "Traceback" not in daemon.log


@pytest.mark.mosquitto
def test_only_the_supervisor_talks_to_systemd(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify"))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)  # each datagram's sender pid
    sock.settimeout(60)
    tables = "".join(
        f'\n[[devices]]\nid = "r{i}"\nreplay = "{write_session(tmp_path / f"r{i}.scotti", 80)}"\n'
        for i in range(2)
    )
    config = tmp_path / "replays.toml"
    config.write_text(
        f'processes = 2\n[source]\nspeed = "max"\n[mqtt]\nbroker = "{mosquitto.url}"\n{tables}'
    )
    env = {"NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "200000"}
    daemon = start_daemon(
        ["--config", str(config), "--model", str(tiny_model_path)], tmp_path / "d.log", env
    )
    got: list[tuple[int, str]] = []
    try:
        while not any("STOPPING=1" in text for _, text in got):
            data, ancillary, _, _ = sock.recvmsg(4096, socket.CMSG_SPACE(12))
            pid = next(
                struct.unpack("3i", bytes(cdata))[0]
                for level, kind, cdata in ancillary
                if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS
            )
            got.append((pid, data.decode()))
    finally:
        sock.close()
    assert daemon.wait(60) == 0, daemon.log[-3000:]  # both replays ended: the whole ends
    assert {pid for pid, _ in got} == {daemon.proc.pid}  # never a worker
    texts = [text for _, text in got]
    assert texts[0] == "READY=1\nSTATUS=2 of 2 worker processes running, 2 devices, 0 restarts"
    assert "WATCHDOG=1" in texts


@pytest.mark.mosquitto
def test_one_device_runs_in_the_daemon_s_own_process(
    mosquitto: Mosquitto, tiny_model_path: Path, tmp_path: Path
) -> None:
    session = write_session(tmp_path / "one.scotti", 60)
    args = ["--replay", str(session), "--speed", "max", "--processes", "2"]
    args += ["--broker", mosquitto.url, "--model", str(tiny_model_path)]
    daemon = start_daemon(args, tmp_path / "one.log")
    assert daemon.wait(60) == 0, daemon.log[-3000:]
    assert "processes = 2: one device, it runs in this process" in daemon.log
    assert "worker 0" not in daemon.log
