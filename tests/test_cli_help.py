"""Every --help reads as plain text: no reST literals (``x``) from the docstrings it
is made of, and the names it gives are the real ones."""

from __future__ import annotations

import importlib
from collections.abc import Callable

import pytest
from scotti.cli.main import VERBS
from scotti.cli.main import main as scotti

HELPS: dict[str, tuple[Callable[[list[str]], object], list[str]]] = {
    **{f"scotti {verb}": (scotti, [verb, "--help"]) for verb in VERBS},
    "scotti": (scotti, ["--help"]),
    "scotti session info": (scotti, ["session", "info", "--help"]),
    "scotti session export": (scotti, ["session", "export", "--help"]),
}
TOOLS = ("faults", "day_soak", "fuzz", "demo", "viewer", "local_broker", "bench")


def help_text(
    run: Callable[[list[str]], object], argv: list[str], capsys: pytest.CaptureFixture[str]
) -> str:
    with pytest.raises(SystemExit) as exit_:
        run(argv)
    assert exit_.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("command", list(HELPS))
def test_scotti_help_has_no_rest_literals(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    if command.split()[-1] in ("train", "export") and importlib.util.find_spec("torch") is None:
        pytest.skip("needs the [train] extra")
    text = help_text(*HELPS[command], capsys)
    assert "usage:" in text
    assert "``" not in text


@pytest.mark.parametrize("tool", TOOLS)
def test_the_tools_help_has_no_rest_literals(tool: str, capsys: pytest.CaptureFixture[str]) -> None:
    module = importlib.import_module(f"scotti.daemon.tools.{tool}")
    text = help_text(module.main, ["--help"], capsys)
    assert "``" not in text


def test_the_daemons_help_has_no_rest_literals(capsys: pytest.CaptureFixture[str]) -> None:
    from scotti.daemon.service.main import main

    text = help_text(main, ["--help"], capsys)
    assert "``" not in text
    assert "--once" in text
    assert "in a loop until stopped" in " ".join(text.split())  # as wrapped


def test_session_info_names_the_session_files_suffix(capsys: pytest.CaptureFixture[str]) -> None:
    text = help_text(scotti, ["session", "info", "--help"], capsys)
    assert "(.scotti)" in text
    assert ".scot)" not in text


def test_a_literal_in_a_verbs_description_is_shown_in_quotes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    text = help_text(scotti, ["sim", "--help"], capsys)
    assert "'corpus', 'render', 'bench' and 'realism'" in text
