"""`scotti sim realism`: the simulator measured against the literature, and the doc it writes."""

from __future__ import annotations

from pathlib import Path

import pytest
from scotti.cli.main import main
from scotti.sim.realism import Realism, measure_population, realism_markdown
from scotti.sim.realism_refs import REFERENCES


@pytest.fixture(scope="module")
def two_subjects() -> Realism:
    return measure_population(count=2, seed=7)


def test_every_measured_figure_of_two_drawn_subjects_is_inside_its_range(
    two_subjects: Realism,
) -> None:
    assert len(two_subjects.rows) == len(REFERENCES)
    outside = [(r.reference.key, r.measured) for r in two_subjects.measured_rows if not r.inside]
    assert outside == []
    # The force figures are measured for every subject (no strike pattern filter).
    forces = [r for r in two_subjects.rows if r.reference.unit == "BW"]
    assert forces
    assert all(len(r.measured) == 2 for r in forces)


def test_markdown_names_every_quantity_its_source_and_the_command(two_subjects: Realism) -> None:
    text = realism_markdown(two_subjects, "scotti sim realism --subjects 2", [])
    assert "`scotti sim realism --subjects 2`" in text
    for ref in REFERENCES:
        assert ref.quantity in text
        assert ref.source in text
    assert "walking_speed_mps" in text  # the drawn traits' spread


def test_cli_writes_the_doc_and_exits_zero_when_everything_is_inside(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "REALISM.md"
    code = main(["sim", "realism", "--subjects", "1", "--no-pictures", "-o", str(out)])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert out.read_text().startswith("# How real the simulated insole is")
    assert "figures inside" in printed


def test_cli_refuses_a_silly_subject_count(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "realism", "--subjects", "0", "--no-pictures"]) == 2
    assert "--subjects" in capsys.readouterr().err
