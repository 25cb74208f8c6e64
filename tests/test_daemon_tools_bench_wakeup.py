"""bench_wakeup times the shipped model's step (real onnxruntime) and a numpy product
after idle gaps: one row per work and gap, figures that are times, and a wrong
argument is one line."""

from __future__ import annotations

import pytest
from scotti.daemon.tools import bench_wakeup


def test_a_row_per_work_and_gap(capsys: pytest.CaptureFixture[str]) -> None:
    assert bench_wakeup.main(["--calls", "2", "--gaps-ms", "0", "1.5"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    body = rows[1:]  # after the header (its rule starts "|-")
    assert [r.split("|")[2].strip() for r in body] == ["0", "1.5", "0", "1.5"]
    assert {r.split("|")[1].strip() for r in body} == {
        "model step, 1 frame",
        "numpy 256x256 product",
    }
    for row in body:
        cpu, wall = float(row.split("|")[3]), float(row.split("|")[4])
        assert cpu > 0
        assert wall > 0
    assert body[0].split("|")[5].strip() == "1.0x"  # each work against its own no-gap call


def test_the_call_after_a_gap_is_timed_after_the_sleep() -> None:
    calls: list[str] = []
    cpu, wall = bench_wakeup.timed_after_gap(lambda: calls.append("x"), 0.02)
    assert len(calls) == bench_wakeup.WARM_CALLS + 1
    assert wall < 20  # the sleep is not in the call's time
    assert cpu >= 0


def test_a_negative_gap_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert bench_wakeup.main(["--gaps-ms", "-1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "gap" in err
