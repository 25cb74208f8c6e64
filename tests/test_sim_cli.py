"""``scotti sim``: scene files, corpora, pictures and the benchmark, through the real dispatcher."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from scotti.cli.main import main
from scotti.firmware_protocol.session import read_session
from scotti.models.contract import ACTIONS
from scotti.sim.corpus import subject_scene
from scotti.sim.subjects import draw_subjects

SCENE = """
description = "two squats with sensor noise"
seed = 4
[subject]
height_m = 1.7
mass_kg = 65.0
style_seed = 1
[[script]]
action = "squat"
reps = 2
stand_s = 0.5
[[effects]]
name = "noise"
std_counts = 3
"""


@pytest.fixture
def scene(tmp_path: Path) -> Path:
    path = tmp_path / "squat.toml"
    path.write_text(SCENE)
    return path


def test_scene_to_session_is_bit_identical_on_rerun(
    scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, b, c = tmp_path / "a.ses", tmp_path / "b.ses", tmp_path / "c.ses"
    assert main(["sim", str(scene), "-o", str(a)]) == 0
    assert main(["sim", str(scene), "-o", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()
    assert main(["sim", str(scene), "-o", str(c), "--seed", "5"]) == 0
    assert c.read_bytes() != a.read_bytes()
    assert main(["sim", str(scene), "-o", str(c), "--force"]) == 0  # --force replaces it
    assert c.read_bytes() == a.read_bytes()
    session = read_session(a)
    assert session.header.source == "simulated"
    assert session.header.scene is not None
    assert session.header.scene["effects"] == [{"name": "noise", "std_counts": 3}]
    assert session.header.subject is not None
    assert session.header.subject["mass_kg"] == 65.0
    assert {label.action for label in session.labels} >= {ACTIONS.index("squat")}
    assert "noise" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sim", "missing.toml", "-o", "x.ses"], "cannot read scene"),
        (["sim", "render", "missing.ses", "-o", "x.png"], "missing.ses"),
        (["sim"], "give a scene file"),
        (["sim", "bench", "--minutes", "0"], "--minutes"),
    ],
)
def test_user_mistakes_are_one_line(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1


def test_bad_effect_in_scene_names_the_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENE.replace("std_counts = 3", "std_counts = -3"))
    assert main(["sim", str(bad), "-o", str(tmp_path / "x.ses")]) == 2
    err = capsys.readouterr().err
    assert "std_counts" in err
    assert err.count("\n") == 1


def test_corpus_writes_sessions_and_manifest(tmp_path: Path) -> None:
    out = tmp_path / "corpus"
    argv = ["sim", "corpus", "-o", str(out), "--subjects", "2", "--minutes-per-action", "0.02"]
    assert main([*argv, "--seed", "3"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["subjects"] == 2
    sessions = manifest["sessions"]
    assert [s["file"] for s in sessions] == ["subject-000.ses", "subject-001.ses"]
    assert sessions[0]["seed"] != sessions[1]["seed"]
    assert read_session(out / "subject-001.ses").header.subject["id"] == "subject-001"  # type: ignore[index]
    assert sessions[0]["subject"] != sessions[1]["subject"]
    assert "packet_loss" in sessions[0]["effects"]
    labels = read_session(out / "subject-000.ses").labels
    assert {label.action for label in labels} == {-1, *range(len(ACTIONS))}
    assert len(labels) == sessions[0]["frames"]
    first = (out / "subject-001.ses").read_bytes()
    assert main([*argv, "--seed", "3", "--effects", "none", "--force"]) == 0
    assert (out / "subject-001.ses").read_bytes() != first
    assert json.loads((out / "manifest.json").read_text())["sessions"][1]["effects"] == []


def test_corpus_extended_with_first_subject_draws_the_same_later_people(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["sim", "corpus", "--minutes-per-action", "0.02", "--seed", "3"]
    assert main([*argv, "-o", str(tmp_path / "all"), "--subjects", "2"]) == 0
    assert (
        main([*argv, "-o", str(tmp_path / "more"), "--subjects", "1", "--first-subject", "1"]) == 0
    )
    more = json.loads((tmp_path / "more" / "manifest.json").read_text())
    assert [s["file"] for s in more["sessions"]] == ["subject-001.ses"]
    assert more["first_subject"] == 1
    # Subject 1 of the extension is subject 1 of the whole: the same person and bytes.
    same = (tmp_path / "all" / "subject-001.ses").read_bytes()
    assert (tmp_path / "more" / "subject-001.ses").read_bytes() == same
    assert (
        main([*argv, "-o", str(tmp_path / "bad"), "--subjects", "1", "--first-subject", "-1"]) == 2
    )
    assert "--first-subject >= 0" in capsys.readouterr().err


def test_render_png_and_gif(scene: Path, tmp_path: Path) -> None:
    session, png, gif = tmp_path / "s.ses", tmp_path / "s.png", tmp_path / "s.gif"
    assert main(["sim", str(scene), "-o", str(session)]) == 0
    argv = ["sim", "render", str(session), "-o", str(png), "--start", "1", "--duration", "1"]
    assert main([*argv, "--gif", str(gif)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")


def test_bench_prints_the_ratio_to_real_time(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "bench", "--minutes", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "ratio to real time:" in out
    assert "one hour:" in out


def test_every_output_that_exists_is_refused_unless_force(
    scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = tmp_path / "s.ses"
    session.write_bytes(b"an earlier session")
    assert main(["sim", str(scene), "-o", str(session)]) == 2
    assert capsys.readouterr().err == f"scotti sim: {session} exists; --force replaces it\n"
    assert session.read_bytes() == b"an earlier session"
    assert main(["sim", str(scene), "-o", str(session), "--force"]) == 0
    assert read_session(session).header.source == "simulated"

    png, gif = tmp_path / "s.png", tmp_path / "s.gif"
    gif.write_bytes(b"kept")
    render = ["sim", "render", str(session), "-o", str(png), "--duration", "0.5"]
    assert main([*render, "--gif", str(gif)]) == 2
    assert capsys.readouterr().err == f"scotti sim: {gif} exists; --force replaces it\n"
    assert not png.exists()  # refused before anything was drawn
    assert main([*render, "--gif", str(gif), "--force"]) == 0
    assert gif.read_bytes()[:3] == b"GIF"


def test_a_corpus_directory_that_holds_session_files_is_refused_unless_force(
    scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "corpus"
    out.mkdir()
    (out / "notes.txt").write_text("not a session")  # other files are no reason to refuse
    argv = ["sim", "corpus", "-o", str(out), "--subjects", "1", "--minutes-per-action", "0.02"]
    assert main(argv) == 0
    capsys.readouterr()
    before = (out / "subject-000.ses").read_bytes()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == f"scotti sim: {out} holds 1 session file; --force writes into it anyway\n"
    assert (out / "subject-000.ses").read_bytes() == before
    assert main([*argv, "--first-subject", "1", "--force"]) == 0  # extended in place
    assert sorted(p.name for p in out.glob("*.ses")) == ["subject-000.ses", "subject-001.ses"]


def test_each_help_says_the_rule(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["sim", "x.toml"], ["sim", "render", "x.ses"], ["sim", "corpus"]):
        with pytest.raises(SystemExit):
            main([*argv, "--help"])
        out = " ".join(capsys.readouterr().out.split())
        assert "unless --force" in out, argv
        assert "--force" in out


def test_corpus_with_wide_paces_records_each_persons_walking_speed(tmp_path: Path) -> None:
    out = tmp_path / "slow"
    argv = ["sim", "corpus", "-o", str(out), "--subjects", "3", "--minutes-per-action", "0.02"]
    assert main([*argv, "--seed", "3", "--paces", "wide", "--effects", "none"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["paces"] == "wide"
    speeds = [s["subject"]["walking_speed_mps"] for s in manifest["sessions"]]
    header = read_session(out / "subject-002.ses").header
    assert header.subject["walking_speed_mps"] == pytest.approx(speeds[2])  # type: ignore[index]
    assert header.scene["subject"]["walking_speed_mps"] is not None  # type: ignore[index]
    # Each person's own drawn pace, where the typical corpus leaves the speed to the style seed.
    people = draw_subjects(3, seed=3)
    given = [
        subject_scene(
            i, p, corpus_seed=3, minutes_per_action=0.02, effects="none", paces="wide"
        ).subject.walking_speed_mps
        for i, p in enumerate(people)
    ]
    assert speeds == pytest.approx(given)
    assert speeds != pytest.approx([p.traits.walking_speed_mps for p in people])


def test_corpus_with_wide_bodies_records_and_renders_each_persons_body(tmp_path: Path) -> None:
    out = tmp_path / "bodies"
    argv = ["sim", "corpus", "-o", str(out), "--subjects", "3", "--minutes-per-action", "0.02"]
    assert main([*argv, "--seed", "3", "--bodies", "wide", "--effects", "none"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["bodies"] == "wide"
    people = draw_subjects(3, seed=3)
    for i, entry in enumerate(manifest["sessions"]):
        scene = subject_scene(
            i, people[i], corpus_seed=3, minutes_per_action=0.02, effects="none", bodies="wide"
        )
        assert entry["subject"]["height_m"] == pytest.approx(scene.subject.height_m)
        assert entry["subject"]["height_m"] != pytest.approx(people[i].height_m)
        session = read_session(out / entry["file"])
        assert session.header.scene["subject"]["foot_length_m"] == scene.subject.foot_length_m  # type: ignore[index]
        assert len(session.labels) > 0


def test_corpus_with_wide_gaits_records_and_renders_each_persons_push_off(tmp_path: Path) -> None:
    out = tmp_path / "gaits"
    argv = ["sim", "corpus", "-o", str(out), "--subjects", "2", "--minutes-per-action", "0.02"]
    assert main([*argv, "--seed", "3", "--gaits", "wide", "--effects", "none"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["gaits"] == "wide"
    people = draw_subjects(2, seed=3)
    for i, entry in enumerate(manifest["sessions"]):
        scene = subject_scene(
            i, people[i], corpus_seed=3, minutes_per_action=0.02, effects="none", gaits="wide"
        )
        assert scene.subject.push_off is not None
        assert entry["subject"]["push_off"] == pytest.approx(scene.subject.push_off)
        session = read_session(out / entry["file"])
        assert session.header.scene["subject"]["push_off"] == scene.subject.push_off  # type: ignore[index]


def test_corpus_with_wide_effects_writes_each_persons_effects_to_its_header(tmp_path: Path) -> None:
    out = tmp_path / "noisy"
    argv = ["sim", "corpus", "-o", str(out), "--subjects", "2", "--minutes-per-action", "0.02"]
    assert main([*argv, "--seed", "3", "--effects", "wide"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["effects"] == "wide"
    people = draw_subjects(2, seed=3)
    for i, entry in enumerate(manifest["sessions"]):
        scene = subject_scene(i, people[i], corpus_seed=3, minutes_per_action=0.02, effects="wide")
        session = read_session(out / entry["file"])
        assert session.header.scene["effects"] == scene.effects  # type: ignore[index]
        assert len(session.labels) > 0
