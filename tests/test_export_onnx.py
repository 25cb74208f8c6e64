"""Exported graphs against torch: checker, parity, streaming, hard inputs, int8, CLI."""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
import onnx
import torch
from scotti.export import export_cli
from scotti.export.errors import ExportError, ParityError
from scotti.export.make_tiny import TINY_CONFIG, build_tiny, tiny_checkpoint
from scotti.export.model import Scotti, ScottiConfig
from scotti.export.onnx_export import load_checkpoint
from scotti.export.parity import (
    check_sane,
    check_structure,
    hard_windows,
    max_abs,
    prove,
    run,
    session,
    sliding_windows,
    stream,
    stream_sequence,
    torch_window,
)
from scotti.models import contract

from tests.support.fixtures_models import TINY_CHECKPOINT, TINY_STEP, TINY_WINDOW

pytestmark = pytest.mark.torch

ATOL = 1e-4  # onnxruntime vs torch, fp32, every output (plus RTOL of the reference)
RTOL = 1e-4
T, E = TINY_CONFIG.window, TINY_CONFIG.embed_dim


@pytest.fixture(scope="module")
def tiny() -> Scotti:
    return load_checkpoint(TINY_CHECKPOINT).model


def test_committed_tiny_checkpoint_is_what_make_tiny_builds(tiny: Scotti) -> None:
    rebuilt = build_tiny().state_dict()
    committed = tiny.state_dict()
    assert rebuilt.keys() == committed.keys()
    for name, value in rebuilt.items():
        assert torch.equal(value, committed[name]), name
    assert tiny.cfg == TINY_CONFIG


def test_committed_tiny_files_are_small() -> None:
    total = sum(p.stat().st_size for p in TINY_STEP.parent.iterdir())
    assert total < 1_000_000


@pytest.mark.parametrize(("path", "graph"), [(TINY_STEP, "step"), (TINY_WINDOW, "window")])
def test_committed_graphs_pass_checker_and_carry_contract_metadata(path: Path, graph: str) -> None:
    check_structure(path, graph)  # onnx.checker (full) + contract I/O names
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert meta[contract.META_CONTRACT_VERSION] == str(contract.CONTRACT_VERSION)
    assert meta[contract.META_GRAPH] == graph
    assert meta[contract.META_WINDOW] == str(T)
    assert meta[contract.META_EMBED_DIM] == str(E)
    assert meta[contract.META_FRAME_ROWS] == str(contract.FRAME_ROWS)
    assert meta[contract.META_FRAME_COLS] == str(contract.FRAME_COLS)
    assert json.loads(meta[contract.META_KEYPOINTS]) == list(contract.KEYPOINTS)
    assert json.loads(meta[contract.META_ACTIONS]) == list(contract.ACTIONS)
    card = json.loads(meta[contract.META_CARD])
    assert card["config"] == TINY_CONFIG.to_dict()
    assert card["contract_version"] == contract.CONTRACT_VERSION


def test_card_files_match_the_committed_graphs() -> None:
    card = json.loads(TINY_STEP.with_suffix("").with_suffix(".card.json").read_text())
    for kind, path in (("step", TINY_STEP), ("window", TINY_WINDOW)):
        assert card["files"][kind]["file"] == path.name
        assert card["files"][kind]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
        assert card["files"][kind]["bytes"] == path.stat().st_size
    assert card["parameters"] == build_tiny().num_parameters()


def test_full_proof_passes_on_committed_graphs(tiny: Scotti) -> None:
    report = prove(tiny, TINY_STEP, TINY_WINDOW)
    assert set(report) == {"window_vs_torch", "step_vs_torch", "stream_vs_window"}
    print(report)


@pytest.mark.parametrize("name", list(hard_windows(TINY_CONFIG)))
def test_window_graph_matches_torch_on_hard_inputs(tiny: Scotti, name: str) -> None:
    frames = hard_windows(TINY_CONFIG)[name][None]  # (1, T, H, 2W)
    got = run(session(TINY_WINDOW), {contract.WINDOW_INPUT_FRAMES: frames})
    want = torch_window(tiny, frames)
    for key, ref in want.items():
        np.testing.assert_allclose(got[key], ref, atol=ATOL, rtol=RTOL, err_msg=f"{name}/{key}")
    check_sane(got, name)  # finite, progress in [0, 1], probabilities sum to 1
    probs = np.exp(got[contract.OUTPUT_ACTION_LOGITS].astype(np.float64))
    np.testing.assert_allclose((probs / probs.sum(-1, keepdims=True)).sum(-1), 1.0, atol=1e-9)
    assert 0.0 <= float(got[contract.OUTPUT_PROGRESS][0]) <= 1.0


def test_clamping_makes_beyond_protocol_counts_equal_saturation() -> None:
    hw = hard_windows(TINY_CONFIG)
    frames = np.stack([hw["saturated"], hw["beyond_protocol"]])
    out = run(session(TINY_WINDOW), {contract.WINDOW_INPUT_FRAMES: frames})
    np.testing.assert_array_equal(out[contract.OUTPUT_POSE][0], out[contract.OUTPUT_POSE][1])


def test_outputs_depend_on_the_input() -> None:
    """A parity check on a constant model would prove nothing: the tiny one reacts."""
    hw = hard_windows(TINY_CONFIG)
    frames = np.stack([hw["zeros"], hw["random"]])
    out = run(session(TINY_WINDOW), {contract.WINDOW_INPUT_FRAMES: frames})
    assert max_abs(out[contract.OUTPUT_POSE][0], out[contract.OUTPUT_POSE][1]) > 100 * ATOL


def test_streamed_steps_match_the_window_graph() -> None:
    """Frame by frame, the cache built from the step's own embeddings, vs whole windows."""
    seq = stream_sequence(TINY_CONFIG, 2 * T + 5)
    streamed = stream(session(TINY_STEP), seq, E, T)
    windowed = run(session(TINY_WINDOW), {contract.WINDOW_INPUT_FRAMES: sliding_windows(seq, T)})
    assert streamed[contract.STEP_OUTPUT_EMBEDDING].shape == (len(seq), E)
    for key, ref in windowed.items():
        np.testing.assert_allclose(streamed[key][T - 1 :], ref, atol=ATOL, rtol=RTOL)
    check_sane(streamed, "stream")


def test_step_graph_matches_torch_with_dynamic_batch(tiny: Scotti) -> None:
    rng = np.random.default_rng(3)
    step = session(TINY_STEP)
    for b in (1, 5):
        frame = rng.uniform(0, contract.MAX_COUNT, (b, *TINY_CONFIG.frame_shape))
        frame = frame.astype(np.float32)
        past = rng.normal(size=(b, T - 1, E)).astype(np.float32)
        got = run(step, {contract.STEP_INPUT_FRAME: frame, contract.STEP_INPUT_PAST: past})
        with torch.no_grad():
            emb = tiny.embed_frames(torch.from_numpy(frame))
            want = tiny.forward_embeddings(torch.cat([torch.from_numpy(past), emb[:, None]], 1))
        np.testing.assert_allclose(got[contract.STEP_OUTPUT_EMBEDDING], emb.numpy(), atol=ATOL)
        np.testing.assert_allclose(got[contract.OUTPUT_POSE], want.pose.numpy(), atol=ATOL)
        assert got[contract.OUTPUT_ACTION_LOGITS].shape == (b, contract.NUM_ACTIONS) == (b, 9)
        np.testing.assert_allclose(
            got[contract.OUTPUT_ACTION_LOGITS], want.action_logits.numpy(), atol=ATOL
        )
        np.testing.assert_allclose(got[contract.OUTPUT_PROGRESS], want.progress.numpy(), atol=ATOL)


def test_proof_catches_a_graph_from_other_weights(tiny: Scotti) -> None:
    other = build_tiny()
    with torch.no_grad():
        last = other.pose_head[-1]
        assert isinstance(last, torch.nn.Linear)
        last.bias.add_(0.01)  # 100x the tolerance on every pose value
    with pytest.raises(ParityError, match="pose differs"):
        prove(other, TINY_STEP, TINY_WINDOW)


# --- the CLI -------------------------------------------------------------------------


def export(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    export_cli.add_arguments(parser)
    return export_cli.run(parser.parse_args(argv))


def test_missing_checkpoint_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert export([str(tmp_path / "nope.pt"), "-o", str(tmp_path / "m.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "checkpoint not found" in err


@pytest.mark.parametrize(
    "fault", ["garbage", "truncated", "no_config", "wrong_shape", "bad_cfg", "contract_v1"]
)
def test_bad_checkpoints_are_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], fault: str
) -> None:
    path = tmp_path / "bad.pt"
    ckpt = tiny_checkpoint(build_tiny())
    if fault == "garbage":
        path.write_bytes(b"not a checkpoint at all\n" * 10)
    elif fault == "truncated":
        path.write_bytes(TINY_CHECKPOINT.read_bytes()[:5000])
    elif fault == "no_config":
        torch.save({"model": ckpt["model"]}, path)
    elif fault == "wrong_shape":
        torch.save({**ckpt, "config": {**TINY_CONFIG.to_dict(), "embed_dim": 64}}, path)
    elif fault == "contract_v1":  # trained before standing: 8 action logits
        state = dict(ckpt["model"])
        for key in ("action_head.3.weight", "action_head.3.bias"):
            state[key] = state[key][:8]
        torch.save({**ckpt, "model": state}, path)
    else:
        torch.save({**ckpt, "config": {**TINY_CONFIG.to_dict(), "heads": 3}}, path)
    assert export([str(path), "-o", str(tmp_path / "m.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith("scotti export: ")
    assert not (tmp_path / "m.onnx").exists()
    if fault == "contract_v1":
        assert "the action head has 8 logits, contract version 2 needs 9" in err


@pytest.mark.slow
def test_cli_exports_proves_and_quantizes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A config unlike the tiny one (short window, 3 layers) end to end, with --int8."""
    cfg = ScottiConfig(
        window=8, embed_dim=24, layers=2, heads=3, conv_channels=(3, 5), head_hidden=16
    )
    torch.manual_seed(7)
    model = Scotti(cfg).eval()
    ckpt = tmp_path / "run.pt"
    metrics = {"mpjpe_mm": 123.4, "action_accuracy": 0.5, "confusion": torch.eye(2)}
    torch.save(
        {"config": cfg.to_dict(), "model": model.state_dict(), "metrics": metrics, "epoch": 3},
        ckpt,
    )
    out = tmp_path / "models" / "run.onnx"
    assert export([str(ckpt), "-o", str(out), "--int8"]) == 0
    printed = capsys.readouterr().out
    print(printed)  # the measured differences, visible with -s
    assert "stream_vs_window" in printed
    assert "int8_window_vs_fp32" in printed
    names = sorted(p.name for p in out.parent.iterdir())
    assert names == [
        "run.card.json",
        "run.card.md",
        "run.int8.onnx",
        "run.int8.window.onnx",
        "run.onnx",
        "run.window.onnx",
    ]
    card = json.loads((out.parent / "run.card.json").read_text())
    assert card["metrics"] == {**metrics, "confusion": [[1.0, 0.0], [0.0, 1.0]]}
    assert card["epoch"] == 3
    assert set(card["files"]) == {"step", "window", "int8_step", "int8_window"}
    assert "123.4" in (out.parent / "run.card.md").read_text()
    # int8: only sanity is asserted; the drift is measured and printed above.
    int8_step, int8_window = out.parent / "run.int8.onnx", out.parent / "run.int8.window.onnx"
    check_structure(int8_step, "step")
    check_structure(int8_window, "window")
    int8_meta = {p.key: p.value for p in onnx.load(str(int8_step)).metadata_props}
    assert json.loads(int8_meta[contract.META_CARD])["precision"].startswith("int8")
    seq = stream_sequence(cfg, 2 * cfg.window)
    check_sane(stream(session(int8_step), seq, 24, 8), "int8 stream")


def test_an_export_that_exists_is_refused_unless_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "models" / "m.onnx"
    assert export([str(TINY_CHECKPOINT), "-o", str(out)]) == 0
    written = {p.name: p.read_bytes() for p in out.parent.iterdir()}
    assert sorted(written) == ["m.card.json", "m.card.md", "m.onnx", "m.window.onnx"]
    capsys.readouterr()
    # Refused before the checkpoint is read: a missing one is not what it says.
    assert export([str(tmp_path / "none.pt"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == f"scotti export: {out} exists (and 3 more of its outputs); --force replaces it\n"
    assert {p.name: p.read_bytes() for p in out.parent.iterdir()} == written
    # Any one file of NAME's export is enough: here an int8 copy left alone.
    lone = tmp_path / "lone"
    lone.mkdir()
    (lone / "m.int8.window.onnx").write_bytes(b"an older model")
    assert export([str(TINY_CHECKPOINT), "-o", str(lone / "m.onnx")]) == 2
    assert "m.int8.window.onnx exists;" in capsys.readouterr().err
    assert [p.name for p in lone.iterdir()] == ["m.int8.window.onnx"]
    # --force replaces the export, and an int8 copy it does not write again goes.
    stale = out.with_name("m.int8.onnx")
    stale.write_bytes(b"an older model")
    (out.parent / "m.card.md").write_text("an older card")
    assert export([str(TINY_CHECKPOINT), "-o", str(out), "--force"]) == 0
    assert not stale.exists()
    assert sorted(p.name for p in out.parent.iterdir()) == sorted(written)
    assert (out.parent / "m.card.md").read_text().startswith("# Model card")  # a new one
    card = json.loads((out.parent / "m.card.json").read_text())
    assert card["files"]["step"]["sha256"] == hashlib.sha256(out.read_bytes()).hexdigest()


def test_export_help_says_the_rule() -> None:
    parser = argparse.ArgumentParser()
    export_cli.add_arguments(parser)
    text = " ".join(parser.format_help().split())
    assert "refused if any of them exists, unless --force" in text
    assert "--force" in text


def test_output_must_end_in_onnx(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert export([str(TINY_CHECKPOINT), "-o", str(tmp_path / "m.bin")]) == 2
    assert "must end in .onnx" in capsys.readouterr().err


def test_load_checkpoint_errors_are_export_errors(tmp_path: Path) -> None:
    path = tmp_path / "list.pt"
    torch.save([1, 2, 3], path)
    with pytest.raises(ExportError, match="not a SCOTTI checkpoint"):
        load_checkpoint(path)
