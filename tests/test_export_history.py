"""``scotti train-history``: a run's history.jsonl drawn into a PNG; bad files are one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from scotti.cli.main import main


def write_history(run: Path, epochs: int, *, plateau_after: int = 0) -> None:
    run.mkdir(parents=True, exist_ok=True)
    lines = []
    for e in range(1, epochs + 1):
        val_loss = max(1.0, 3.0 - 0.5 * e)  # falls, then flat: a plateau
        record = {
            "epoch": e,
            "train_loss": 3.0 / e,
            "val": {"loss": val_loss, "progress_mse": 0.1 / e, "app": 0.5 + 0.05 * e},
            "best_epoch": min(e, 4),
        }
        record["val"]["action_accuracy"] = 0.3 + 0.06 * e
        if e == plateau_after:
            record["status"] = "plateau"
        lines.append(json.dumps(record))
    (run / "history.jsonl").write_text("\n".join(lines) + "\n")


def test_history_is_drawn_into_a_png(tmp_path: Path) -> None:
    run = tmp_path / "run"
    write_history(run, 8, plateau_after=8)
    out = tmp_path / "plots" / "history.png"
    assert main(["train-history", str(run), "-o", str(out)]) == 0
    image = matplotlib.image.imread(out)
    assert image.shape[1] > image.shape[0] > 200  # four panels side by side
    assert float(np.std(image[..., :3])) > 0.05  # something was drawn, not a blank page
    # The default place is the run directory; the module runs on its own too.
    done = subprocess.run(
        [sys.executable, "-m", "scotti.export.history", str(run / "history.jsonl")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert (run / "history.png").is_file()


def test_a_png_that_exists_is_drawn_again_only_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    write_history(run, 3)
    out = run / "history.png"
    out.write_bytes(b"an earlier drawing")
    assert main(["train-history", str(run)]) == 2
    err = capsys.readouterr().err
    assert err == f"scotti train-history: {out} exists; --force replaces it\n"
    assert out.read_bytes() == b"an earlier drawing"
    assert main(["train-history", str(run), "--force"]) == 0
    assert matplotlib.image.imread(out).shape[0] > 200
    with pytest.raises(SystemExit):
        main(["train-history", "--help"])
    assert "unless --force" in " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (None, "No such file"),
        ("", "no epochs"),
        ("{oops\n", "not a JSON line"),
        ('{"x": 1}\n', "epoch"),
    ],
)
def test_bad_histories_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str | None, words: str
) -> None:
    run = tmp_path / "run"
    run.mkdir()
    if content is not None:
        (run / "history.jsonl").write_text(content)
    assert main(["train-history", str(run), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("scotti train-history:")
    assert words in err
    assert "\n" not in err
    assert not (tmp_path / "x.png").exists()
