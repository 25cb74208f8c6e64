"""``scotti session relabel``: a simulated session written under one labelling
convention (the one in force) gets the other's progress labels (steps cut at
the indicator's peaks or after each landing), and nothing else of it changes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.cli.main import main
from scotti.firmware_protocol.session import SessionReader, SessionWriter
from scotti.firmware_protocol.session_records import LabelRecord, PacketRecord, SessionHeader
from scotti.models.contract import ACTIONS, FRAME_RATE_HZ
from scotti.models.progress import STEP_CUTS, PeakParams, label_progress
from scotti.sim.actions import Context
from scotti.sim.motion import labels
from scotti.sim.relabel import relabel_session
from scotti.sim.scene import ScriptEntry, SubjectModel, motion_from_segments, script_segments
from scotti.sim.writer import sim_input, write_session


def _walk_motion():  # type: ignore[no-untyped-def]
    subject = SubjectModel(height_m=1.7, mass_kg=70.0, style_seed=3).subject()
    ctx = Context(subject.body(), subject, FRAME_RATE_HZ, np.random.default_rng(1))
    entries = [ScriptEntry(action="walking", reps=10), ScriptEntry(action="squat", reps=3)]
    return motion_from_segments(ctx.body, ctx.subject, ctx.rate_hz, script_segments(ctx, entries))


# The convention not in force: relabelling into it changes walking's labels.
OTHER = PeakParams(step_cut=next(c for c in STEP_CUTS if c != PeakParams().step_cut))


@pytest.fixture(scope="module")
def old_and_new(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """A walk and squats rendered under the convention in force, and the same
    motion's labels under the other."""
    motion = _walk_motion()
    truth = labels(motion)
    other = label_progress(truth.keypoints, truth.action, OTHER)
    path = tmp_path_factory.mktemp("relabel") / "old.ses"
    write_session(path, sim_input(motion), seed=4)
    return path, other


def _records(path: Path) -> tuple[list[PacketRecord], list[LabelRecord]]:
    with SessionReader(path) as reader:
        records = list(reader)
    return (
        [r for r in records if isinstance(r, PacketRecord)],
        [r for r in records if isinstance(r, LabelRecord)],
    )


def test_relabelled_file_has_the_other_conventions_labels_and_the_same_packets(
    old_and_new: tuple[Path, object], tmp_path: Path
) -> None:
    old_path, other = old_and_new
    out = tmp_path / "new.ses"
    report = relabel_session(old_path, out, OTHER)
    old_packets, old_labels = _records(old_path)
    new_packets, new_labels = _records(out)
    assert [(p.t_ns, p.data) for p in new_packets] == [(p.t_ns, p.data) for p in old_packets]
    assert [(r.seq, r.t_ns, r.action) for r in new_labels] == [
        (r.seq, r.t_ns, r.action) for r in old_labels
    ]
    got = np.array([r.progress for r in new_labels], dtype=np.float32)
    np.testing.assert_allclose(got, other.progress, atol=1e-6)  # type: ignore[attr-defined]
    np.testing.assert_array_equal([r.rep for r in new_labels], other.repetition)  # type: ignore[attr-defined]
    walking = np.array([r.action for r in old_labels]) == ACTIONS.index("walking")
    was = np.array([r.progress for r in old_labels], dtype=np.float32)
    # The old file really was labelled otherwise: some walking frames moved, no squat did.
    assert report.changed > 0
    assert not np.allclose(was[walking], got[walking], atol=1e-6)
    np.testing.assert_allclose(was[~walking], got[~walking], atol=1e-6)
    with SessionReader(out) as a, SessionReader(old_path) as b:
        assert a.header == b.header


def test_the_command_writes_under_out_and_leaves_existing_files(
    old_and_new: tuple[Path, object], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    old_path, _ = old_and_new
    folder = tmp_path / "corpus" / "realistic"
    folder.mkdir(parents=True)
    (folder / "a.ses").write_bytes(old_path.read_bytes())
    out = tmp_path / "out"
    relabel = ["session", "relabel", str(tmp_path / "corpus"), "--out", str(out)]
    assert main([*relabel, "--step-cut", OTHER.step_cut]) == 0
    written = out / "realistic" / "a.ses"
    assert written.is_file()
    assert "labels changed" in capsys.readouterr().out
    before = written.read_bytes()
    assert main(relabel) == 1
    assert "--force" in capsys.readouterr().err
    assert written.read_bytes() == before
    assert not list(out.rglob("*.tmp"))


def test_a_recording_is_refused_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recorded = tmp_path / "rec.ses"
    with SessionWriter(recorded, SessionHeader(source="recorded")) as writer:
        writer.write_packet(1, b"\x00")
    assert main(["session", "relabel", str(recorded), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "only simulated sessions" in err
    assert "Traceback" not in err
    assert not (tmp_path / "o" / "rec.ses").exists()


def test_a_missing_path_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["session", "relabel", str(tmp_path / "none"), "--out", str(tmp_path)]) == 2
    assert "no such file" in capsys.readouterr().err


def test_a_source_cut_short_is_copied_whole_records_and_said(
    old_and_new: tuple[Path, object], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    old_path, _ = old_and_new
    data = old_path.read_bytes()
    cut = tmp_path / "cut.ses"
    cut.write_bytes(data[: len(data) - 7])  # a render killed inside its last record
    out = tmp_path / "out"
    assert main(["session", "relabel", str(cut), "--out", str(out)]) == 0
    assert "cut short" in capsys.readouterr().out
    with SessionReader(out / "cut.ses") as copy:
        records = list(copy)
        assert not copy.truncated  # the copy itself is whole
    with SessionReader(cut) as source:
        assert len(records) == len(list(source))  # every whole record of the source
