"""``scotti session info``: good, cut, wrapped and bad files; in-process and as a command."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from scotti.cli.main import main
from scotti.firmware_protocol.session import SessionHeader, SessionWriter
from scotti.firmware_protocol.session_summary import summarize

from tests.support.protocol import write_demo_session


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sessions") / "demo.scot"
    # 40 frames from seq 65530: wraps, seqs 65535 and 3 never sent, left block 2 of seq 5 lost
    write_demo_session(path, frames=40, skip_seqs=(65535, 3), drop_block=(5, 2), start_seq=65530)
    return path


def test_summary_counts_what_the_file_holds(demo: Path) -> None:
    s = summarize(demo)
    left, right = s.feet["left"], s.feet["right"]
    assert (left.frames, right.frames) == (38, 38)
    assert (left.blocks, right.blocks) == (38 * 4 - 1, 38 * 4)
    assert (left.incomplete_frames, left.rows_missing, right.incomplete_frames) == (1, 8, 0)
    assert (left.gaps, left.frames_lost, right.gaps, right.frames_lost) == (2, 2, 2, 2)
    assert (left.first_seq, left.last_seq) == (65530, 33)
    assert s.decoder["bad_cobs"] == 1
    assert s.decoder["packets"] == 38 * 8 - 1 + 3
    assert s.labels.count == 38
    assert s.labels.actions == {-1: 20, 0: 18}
    assert s.status.reports == 3
    assert s.status.link_down_reports == {"left": 0, "right": 3}
    assert s.duration_s == pytest.approx(40 * 0.0625)  # garbage record, then 40 frame slots
    assert not s.truncated
    # As the daemon pairs them: the two lost moments bridged with both feet held.
    assert (s.pairing["pairs_out"], s.pairing["gaps"], s.pairing["held"]) == (40, 2, [2, 2])
    assert (s.pairing["rows_missing"], s.pairing["restarts"]) == (1, 0)


def test_info_text(demo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["session", "info", str(demo)]) == 0
    out = capsys.readouterr().out
    assert "simulated, device 'demo'" in out
    assert "32 x 22, 12-bit samples, 16 Hz" in out
    assert "name=demo seed=1" in out
    lines = {line.split("  ")[1].strip(): line.split()[-2:] for line in out.splitlines()[5:15]}
    assert lines["frames"] == ["38", "38"]
    assert lines["incomplete frames"] == ["1", "0"]
    assert lines["sequence gaps"] == ["2", "2"]
    assert "bad packets bad_cobs=1" in out
    assert "pairs     40 as the daemon pairs them; held left 2, right 2;" in out
    assert "labels    38" in out
    assert "link DOWN" in out
    assert "complete (ends on a whole record)" in out


def test_info_json(demo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["session", "info", str(demo), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["header"]["source"] == "simulated"
    assert data["feet"]["right"]["frames"] == 38
    assert data["decoder"]["bad_cobs"] == 1
    assert data["labels"]["actions"] == {"-1": 20, "0": 18}
    assert data["status"]["last"]["left"]["battery_mv"] == 3700
    assert data["truncated"] is False


def test_info_on_a_cut_file(demo: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.scot"
    raw = demo.read_bytes()
    cut.write_bytes(raw[: len(raw) // 2])
    assert main(["session", "info", str(cut), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["truncated"] is True
    assert 0 < data["feet"]["left"]["frames"] < 38
    assert main(["session", "info", str(cut)]) == 0
    assert "TRUNCATED" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("content", "words"),
    [(None, "cannot open session file"), (b"[tool]\nname = 1\n", "is not a session file")],
)
def test_bad_files_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes | None, words: str
) -> None:
    path = tmp_path / "x.scot"
    if content is not None:
        path.write_bytes(content)
    assert main(["session", "info", str(path)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert words in captured.err
    assert captured.err.count("\n") == 1
    assert captured.err.startswith("scotti session: ")


def test_as_a_command(demo: Path, tmp_path: Path) -> None:
    command = shutil.which("scotti", path=str(Path(sys.executable).parent))
    assert command is not None
    done = subprocess.run(
        [command, "session", "info", str(demo)], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    assert "frames lost in gaps" in done.stdout
    missing = subprocess.run(
        [command, "session", "info", str(tmp_path / "none.scot")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert missing.returncode == 2
    assert "Traceback" not in missing.stderr
    assert len(missing.stderr.splitlines()) == 1


def test_info_names_the_actions_and_says_when_there_is_no_clock(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from scotti.models.contract import ACTIONS

    from tests.support.sessions import write_synthetic_session

    session = write_synthetic_session(tmp_path / "s.scotti", frames=32)  # actions 0 and 1
    assert main(["session", "info", str(session.path)]) == 0
    out = capsys.readouterr().out
    (labels,) = [line for line in out.splitlines() if line.startswith("labels")]
    assert f"{ACTIONS[0]}: 16, {ACTIONS[1]}: 16" in labels
    assert "action 0" not in labels
    header = SessionHeader(source="simulated", created_unix=0.0)
    with SessionWriter(tmp_path / "sim.scotti", header):
        pass
    assert main(["session", "info", str(tmp_path / "sim.scotti")]) == 0
    out = capsys.readouterr().out
    assert "1970" not in out
    assert "created - (simulated files carry no wall clock)" in out
