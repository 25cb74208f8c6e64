"""The fuzzer's inputs and checks at a small count (the million-input run is a command)."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scotti.daemon.tools import fuzz, fuzz_inputs

SETTINGS = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@SETTINGS
@given(st.randoms(use_true_random=False))
def test_decoder_takes_anything(rnd: random.Random) -> None:
    fuzz_inputs.check_decoder(fuzz_inputs.make_decoder_input(rnd))


@SETTINGS
@given(st.randoms(use_true_random=False))
def test_assembler_and_pairing_take_any_blocks(rnd: random.Random) -> None:
    fuzz_inputs.check_assembler(fuzz_inputs.make_blocks(rnd))


@SETTINGS
@given(st.randoms(use_true_random=False))
def test_session_reader_takes_any_file(tmp_path: Path, rnd: random.Random) -> None:
    seed = fuzz_inputs.session_seed(tmp_path)
    fuzz_inputs.check_session(fuzz_inputs.make_session_bytes(rnd, seed), tmp_path)


@SETTINGS
@given(st.randoms(use_true_random=False))
def test_config_loader_takes_any_toml(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, rnd: random.Random
) -> None:
    monkeypatch.delenv("SCOTTI_MQTT_BROKER", raising=False)
    fuzz_inputs.check_config(fuzz_inputs.make_toml(rnd), tmp_path)


def test_a_finding_is_kept_and_the_run_goes_on(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    def check(x: float) -> None:
        if x < 0.5:
            raise ValueError("boom")

    monkeypatch.setattr(fuzz, "target", lambda *_args: (lambda rnd: rnd.random(), check))
    outcome = fuzz.fuzz("fake", 50, 0, tmp_path, 0, float("inf"))
    assert outcome.inputs == 50  # it did not stop at the first
    assert list(outcome.findings) == ["ValueError at test_daemon_tools_fuzz.py:51: boom"]


def test_the_first_run_s_finding_stays_fixed(tmp_path: Path) -> None:
    """A 5,000-character replay path raised OSError (file name too long) from is_file()."""
    fuzz_inputs.check_config('[source]\nreplay = "' + "x" * 5000 + '"\n', tmp_path)


def test_the_command_prints_its_table(capsys: pytest.CaptureFixture[str]) -> None:
    targets = ("decoder", "assembler", "session", "config")  # the import targets: their own test
    assert fuzz.main(["--inputs", "80", "--progress", "0", "--targets", ",".join(targets)]) == 0
    out = capsys.readouterr().out
    assert "| all | 80 | 0 |" in out
    for target in targets:
        assert f"| {target} | 20 | 0 |" in out


def test_a_seq_that_comes_round_again_is_a_new_frame_not_a_finding() -> None:
    """The first run's two assembler findings: jumps ahead that add up to a wrap."""
    import numpy as np
    from scotti.firmware_protocol.packets import Foot, FrameRows

    def whole(seq: int) -> FrameRows:
        return FrameRows(Foot.LEFT, seq, 0, 32, 22, 12, 0, np.zeros((32, 22), np.uint16))

    fuzz_inputs.check_assembler([(whole(s), 0) for s in (4, 20_004, 40_004, 4)])


def test_the_session_target_s_bombs_land_as_records_and_are_refused(tmp_path: Path) -> None:
    # Imported here: a test above names its own line numbers.
    from scotti.firmware_protocol.errors import SessionError
    from scotti.firmware_protocol.session import read_session

    seed = fuzz_inputs.session_seed(tmp_path)
    rnd = random.Random(41)
    refused = read = 0
    for _ in range(200):
        data = fuzz_inputs.session_with_bomb(rnd, seed)
        fuzz_inputs.check_session(data, tmp_path)
        try:
            read_session(tmp_path / "fuzzed.scotti")
            read += 1
        except SessionError as exc:
            refused += "is corrupt at byte" in str(exc)  # over a limit, at its byte
    assert refused > 20  # the bombs reach the reader as records, which stops at them
    assert read > 20  # and the ones within the limits (a few levels deep) read


@pytest.mark.parametrize("draw", [0, 1])
def test_full_size_bombs_are_read_in_bounded_memory(tmp_path: Path, draw: int) -> None:
    """16 MiB bombs: the reader took 1.2 GB and 15 s; the check allows 256 MiB."""
    from scotti.firmware_protocol.errors import SessionError
    from scotti.firmware_protocol.session import read_session

    seed = fuzz_inputs.session_seed(tmp_path)
    rnd = random.Random(draw)
    bomb = fuzz_inputs.full_size_bomb(rnd)
    fuzz_inputs.check_session(seed + len(bomb).to_bytes(4, "little") + bomb, tmp_path)
    words = r"corrupt at byte \d+: (an array of \d+ entries|more than \d+ values)"
    with pytest.raises(SessionError, match=words):
        read_session(tmp_path / "fuzzed.scotti")
