"""bench_floor reads real bytes from emulated boards through pseudo-terminals, with the
daemon's serial transport and with raw reads, hands every pair-frame through its
engine stand-in and writes its messages to a real socket: rows that count what it
did, and a wrong argument is a usage error, not a traceback."""

from __future__ import annotations

import asyncio
import socket

import pytest
from scotti.daemon.tools import bench_floor


def test_a_row_per_pairs_and_reader(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--pairs", "2", "--seconds", "1.5", "--warmup", "1"]
    assert bench_floor.main(argv) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    body = [[cell.strip() for cell in row.split("|")[1:-1]] for row in rows[1:]]
    assert [(r[0], r[1]) for r in body] == [("2", "serial"), ("2", "raw")]
    for _pairs, _reader, percent, us, model_us, budget, ratio in body:
        assert float(percent) > 0
        assert float(us) > 0
        assert float(budget) == pytest.approx(float(model_us) / 2, abs=1)
        assert float(ratio) == pytest.approx(float(us) / float(budget), rel=0.05)


def test_every_pair_frame_read_is_delivered_and_written() -> None:
    """Twelve pair-frames (more than a model call's MAX_BATCH) in, twelve out, and
    their messages reach the other end of the socket."""

    async def run() -> tuple[int, int]:
        out, far = socket.socketpair()
        out.setblocking(False)
        hub = bench_floor.Hub(asyncio.get_running_loop(), out)
        for board in range(12):
            hub.submit(board)
        for _ in range(200):
            if hub.delivered == 12:
                break
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.05)  # the flush is the next turn's
        hub.stop()
        far.setblocking(False)
        got = len(far.recv(1 << 16))
        out.close()
        far.close()
        return hub.delivered, got

    delivered, got = asyncio.run(run())
    assert delivered == 12
    assert got == 12 * len(bench_floor.MESSAGES)


def test_no_pairs_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        bench_floor.main(["--pairs", "0"])
    assert exit_.value.code == 2
    assert "--pairs must be >= 1" in capsys.readouterr().err
