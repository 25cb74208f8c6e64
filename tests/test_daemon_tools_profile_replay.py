"""profile_replay: the daemon's event loop profiled on a replay, by part of the path."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from scotti.daemon.tools import profile_replay

from tests.support.sessions import write_synthetic_session

pytestmark = [pytest.mark.mosquitto, pytest.mark.slow]


def test_prints_the_rate_and_the_parts_of_the_path(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=60).path
    args = [str(session), "--model", str(tiny_model_path), "--top", "3", "--fallback-cobs"]
    assert profile_replay.main(args) == 0
    out = capsys.readouterr().out
    assert "COBS decoder: fallback" in out
    rate = re.search(r"(\d+) paired frames in [\d.]+ s, (\d+) frames/s", out)
    assert rate is not None, out
    assert int(rate.group(1)) == 60
    shares = dict(re.findall(r"^  (\S[^\n]*?)\s+[\d.]+ s\s+([\d.]+) %$", out, re.MULTILINE))
    assert "COBS + packet decoding" in shares
    assert abs(sum(float(v) for v in shares.values()) - 100) < 1


def test_a_missing_session_is_one_line_and_status_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert profile_replay.main([str(tmp_path / "nope.scotti")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "no such session file" in err
