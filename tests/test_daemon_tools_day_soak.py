"""The day soak at a few hundred frames (the 1.38 million are a command), and its bytes."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from scotti.daemon.tools import day_soak
from scotti.daemon.tools.generated import GeneratedBoard
from scotti.firmware_protocol.framing import decode_all
from scotti.firmware_protocol.packets import FrameRows


def test_generated_bytes_are_what_a_receiver_sends_with_seqs_wrapping() -> None:
    chunks = GeneratedBoard().chunks(65535, 2)
    seen = []
    for chunk in chunks:
        packets, counters = decode_all(chunk)
        assert counters.errors == 0
        assert len(packets) == 8  # four row blocks per foot
        seen += [(int(p.foot), p.seq) for p in packets if isinstance(p, FrameRows)]
    assert seen[0] == (0, 65535)
    assert seen[-1] == (1, 0)  # wrapped


@pytest.mark.mosquitto
@pytest.mark.slow
def test_the_soak_runs_the_daemon_and_reports_rss(
    tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = day_soak.main(["--frames", "400", "--every", "200", "--model", str(tiny_model_path)])
    out = capsys.readouterr().out
    assert code == 0, out
    rows = re.findall(r"^\s+(\d+)\s+(\d+)\s+(\d+)\s+([\d.]+)", out, re.M)
    assert [int(r[0]) for r in rows] == [200, 400]
    predictions = re.search(r"(\d+) predictions in", out)
    assert predictions is not None, out
    assert int(predictions.group(1)) == 400 - 39  # every frame after the warm-up predicted
    assert "growth" in out
