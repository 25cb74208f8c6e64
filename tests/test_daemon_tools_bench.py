"""The bench end to end, its subscriber (it stops on time even while poses keep pouring
in) and its config."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import aiomqtt
import pytest
from scotti.daemon.tools.bench import PERIOD_NS, board_records, collect
from scotti.daemon.tools.local_broker import Mosquitto


def test_board_records_are_four_row_blocks_per_foot_frame() -> None:
    records = board_records(1.0)
    assert len(records) == 16 * 2 * 4  # 16 Hz, two feet, 4 packets of 8 rows
    assert records[8][0] == PERIOD_NS  # the second frame starts one period later


@pytest.mark.mosquitto
def test_collect_ends_on_time_under_a_flood_of_poses(mosquitto: Mosquitto) -> None:
    async def body() -> tuple[int, float]:
        async with aiomqtt.Client(mosquitto.host, mosquitto.port) as client:
            stop = asyncio.Event()

            async def flood() -> None:
                while not stop.is_set():
                    now = time.monotonic_ns()
                    pose = {"latency_ms": 1.0, "predicted_for_mono_ns": now + PERIOD_NS}
                    await client.publish("scotti/bench/pose", json.dumps(pose))
                    await asyncio.sleep(0)

            flooder = asyncio.create_task(flood())
            start = time.monotonic()
            samples = await collect(mosquitto, seconds=1.0, warmup=0.2)
            took = time.monotonic() - start
            stop.set()
            await flooder
        return len(samples), took

    got, took = asyncio.run(body())
    assert got > 0  # it did read the flood after the warm-up
    assert took < 5.0  # and still stopped: the timeout was not swallowed


def test_bench_percentiles_and_the_health_ring_summarise_alike() -> None:
    from scotti.daemon.service.counters import LatencyRing
    from scotti.daemon.tools.bench import percentiles

    values = [1.0, 2.0, 3.0, 10.0]
    ring = LatencyRing(8)
    for v in values:
        ring.add(v)
    s = ring.summary()
    assert s == {"n": 4, "p50": 2.5, "p90": 7.9, "p99": 9.79, "max": 10.0}
    assert percentiles(values) == "p50   2.50  p90   7.90  p99   9.79  max  10.00 ms"
    assert percentiles([]) == "no samples"
    assert LatencyRing().summary()["n"] == 0


@pytest.mark.mosquitto
def test_the_bench_runs_two_pairs_in_one_daemon_and_prints_their_row(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from scotti.daemon.tools.bench import main
    from scotti.daemon.tools.bench_table import HEADER

    code = main(["--pairs", "2", "--seconds", "1.5", "--warmup", "0.5", "--modes", "batch"])
    out = capsys.readouterr().out
    assert code == 0, out
    rows = [line for line in out.splitlines() if line.startswith("| 2 | batched, gather 4 ms |")]
    assert len(rows) == 1, out
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    header = [c.strip() for c in HEADER.strip("|").split("|")]
    column = dict(zip(header, cells, strict=True))
    assert float(column["poses/s per pair"]) > 0  # both devices published
    assert float(column["RSS MiB"]) > 0  # the daemon's RSS was sampled
    assert 1 <= float(column["frames per model call"]) <= 2  # from the engine, via health
    model, ratio = float(column["model per pair"]), column["daemon / model"]
    assert model > 0  # the model floor was measured beside the daemon
    per_pair = float(column["per pair"])
    expected = per_pair / model  # from the printed cells, each rounded to 0.01
    assert ratio.endswith("x")
    # The ratio is printed to 0.1 from unrounded figures; the cells' rounding moves
    # the quotient by up to 0.005 / model + 0.005 / per_pair of itself (a model cell
    # of 0.31 alone: 1.6 %).
    rounding = 0.05 + expected * (0.005 / model + 0.005 / per_pair) + 1e-9
    assert abs(float(ratio[:-1]) - expected) <= rounding
    # Simulated people, not random maps: the poses are not flagged out_of_range.
    out_of_range = float(column["flagged out_of_range / unloaded / unfamiliar %"].split("/")[0])
    assert out_of_range < 5.0
    peaks = [line for line in out.splitlines() if line.startswith("| 2 | 1 | MQTT only |")]
    assert len(peaks) == 1, out
    rss, threads, fds = (float(c) for c in peaks[0].strip("|").split("|")[3:])
    assert rss >= float(column["RSS MiB"])  # from the start: at least the steady state's peak
    assert threads >= 2  # the event loop and the inference worker
    assert fds >= 2 + 3  # two serial ports beside stdin, stdout and stderr


def test_the_old_bench_command_still_answers() -> None:
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "scotti.daemon.tools.bench", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0
    assert "--pairs" in done.stdout


def test_everything_turns_on_what_the_units_limits_must_allow(tmp_path: Path) -> None:
    from scotti.daemon.settings import load_settings
    from scotti.daemon.tools.bench import config_text

    links = [tmp_path / "tty00", tmp_path / "tty01"]
    broker = Mosquitto()  # only its URL: nothing is started
    for processes, outputs in ((1, True), (2, False)):  # outputs serve one process only
        path = tmp_path / f"p{processes}.toml"
        path.write_text(config_text(links, broker, True, processes=processes, everything=True))
        s = load_settings({}, path)
        assert s.mqtt.control
        assert (s.outputs.web is not None, s.outputs.foxglove is not None) == (outputs, outputs)
        assert [d.id for d in s.device_list()] == ["pair00", "pair01"]
    path.write_text(config_text(links, broker, True))
    plain = load_settings({}, path)
    assert not plain.mqtt.control
    assert not plain.outputs.any


def test_a_daemon_from_another_checkout_runs_first_with_its_own_defaults(tmp_path: Path) -> None:
    """--daemon-from: that checkout's daemon is run before this one's, batched and per
    pair alike, with no ``gather_ms`` key (a daemon from before the setting refuses it)."""
    from scotti.daemon.tools.bench import _engine_modes, config_text
    from scotti.daemon.tools.local_broker import Mosquitto

    old = tmp_path / "before"
    runs = _engine_modes([True, False], [0.0, 4.0], old)
    assert runs == [
        (True, None, old),
        (False, None, old),
        (True, 0.0, None),
        (True, 4.0, None),
        (False, 0.0, None),
    ]
    assert _engine_modes([True], [4.0], None) == [(True, 4.0, None)]
    broker = Mosquitto(port=1883)  # not started: only its url is read
    theirs = config_text([tmp_path / "tty0"], broker, True, gather_ms=None)
    ours = config_text([tmp_path / "tty0"], broker, True, gather_ms=4.0)
    assert "gather_ms" not in theirs
    assert "gather_ms = 4.0\n" in ours
