"""One checkpoint -> the two ONNX graphs the daemon runs, a model card, and proof.

NAME.onnx is the streaming step (one new frame + the cached embeddings of the
previous T-1 frames -> pose, action logits, progress and the new frame's
embedding); NAME.window.onnx takes B whole windows. Both come from the same
weights via the dynamo exporter (opset 20), carry the contract metadata, and
are checked against torch (``scotti.export.parity``) before the card is
written. Optional int8 copies quantize MatMul/Gemm only (``quantize.py``).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import logging
import os
import tempfile
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import onnx
import torch
from scotti.export.calibration_draws import InputDraws
from scotti.export.card import card_markdown, file_entry, jsonable, tool_versions
from scotti.export.errors import ExportError
from scotti.export.kv_export import KV_GRAPH, KvStepGraph, kv_metadata, prove_kv, step_example
from scotti.export.model import ModelConfigError, Scotti, ScottiConfig
from scotti.export.ood_calibration import Calibration, calibrate, gather
from scotti.export.parity import (
    FP32,
    STEP_INPUTS,
    STEP_OUTPUTS,
    WINDOW_INPUTS,
    WINDOW_OUTPUTS,
    Report,
    Tolerance,
    drift,
    prove,
)
from scotti.export.progress_fit import fit_progress
from scotti.export.quantize import quantize_int8
from scotti.export.subnormals import zero_subnormal_weights
from scotti.models import contract
from scotti.models.input_checks import input_check_thresholds
from scotti.models.kv_contract import KV_STEP_INPUTS, KV_STEP_OUTPUTS
from scotti.models.ood import OodStats
from scotti.models.progress_calibration import ProgressCalibration
from torch import nn

OPSET = 20


class StepGraph(nn.Module):
    """The streaming step: what the daemon runs once per new frame."""

    def __init__(self, model: Scotti) -> None:
        super().__init__()
        self.model = model

    def forward(
        self, frame: torch.Tensor, past_embeddings: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        emb = self.model.embed_frames(frame)  # (B, E), the newest frame
        window = torch.cat([past_embeddings, emb[:, None]], dim=1)  # (B, T, E), oldest first
        (pose, action_logits, progress), pooled = self.model.forward_embeddings_pooled(window)
        return pose, action_logits, progress, emb, pooled


class WindowGraph(nn.Module):
    """B whole windows of raw frames, for batch evaluation."""

    def __init__(self, model: Scotti) -> None:
        super().__init__()
        self.model = model

    def forward(
        self, frames: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        b, t, h, w2 = frames.shape
        emb = self.model.embed_frames(frames.reshape(b * t, h, w2)).view(b, t, -1)  # (B, T, E)
        (pose, action_logits, progress), pooled = self.model.forward_embeddings_pooled(emb)
        return pose, action_logits, progress, pooled


@dataclass(frozen=True)
class Checkpoint:
    """What ``torch.save`` wrote: config + weights, and what the card reports."""

    model: Scotti
    training_data: Any = None
    metrics: Any = None
    epoch: int | None = None
    options: dict[str, Any] | None = None  # the last training run's (train_options.py)


@dataclass(frozen=True)
class GraphPaths:
    """The files of one export, named after NAME.onnx (the step graph)."""

    step: Path
    window: Path
    card_json: Path
    card_md: Path
    int8_step: Path
    int8_window: Path

    @classmethod
    def for_output(cls, out: Path) -> GraphPaths:
        if out.suffix != ".onnx":
            msg = f"output must end in .onnx: {out}"
            raise ExportError(msg)
        base = out.with_suffix("")
        return cls(
            step=out,
            window=base.with_suffix(".window.onnx"),
            card_json=base.with_suffix(".card.json"),
            card_md=base.with_suffix(".card.md"),
            int8_step=base.with_suffix(".int8.onnx"),
            int8_window=base.with_suffix(".int8.window.onnx"),
        )

    def all(self) -> list[Path]:
        """Every file of the export, the int8 copies too (written with --int8 only)."""
        return [self.step, self.window, self.card_json, self.card_md, *self.int8()]

    def int8(self) -> list[Path]:
        return [self.int8_step, self.int8_window]


@dataclass
class ExportResult:
    paths: GraphPaths
    card: dict[str, Any]
    parity: dict[str, dict[str, float]]  # check -> output -> max abs difference
    int8_drift: dict[str, dict[str, float]] = field(default_factory=dict)


def load_checkpoint(path: Path) -> Checkpoint:
    """Read a training checkpoint; any fault is one ``ExportError`` line."""
    if not path.is_file():
        msg = f"checkpoint not found: {path}"
        raise ExportError(msg)
    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a bad file
        kind = type(exc).__name__
        msg = f"cannot read checkpoint {path}: corrupt, truncated or not a torch.save file ({kind})"
        raise ExportError(msg) from None
    if not isinstance(raw, dict) or "config" not in raw or "model" not in raw:
        msg = f"{path} is not a SCOTTI checkpoint (needs the keys 'config' and 'model')"
        raise ExportError(msg)
    try:
        cfg = ScottiConfig.from_dict(dict(raw["config"]))
    except (ModelConfigError, TypeError, ValueError) as exc:
        msg = f"{path}: bad config: {exc}"
        raise ExportError(msg) from None
    model = Scotti(cfg)
    _load_weights(model, raw["model"], path)
    epoch = raw.get("epoch")
    return Checkpoint(
        model=model.eval(),
        training_data=raw.get("training_data"),
        metrics=raw.get("metrics"),
        epoch=int(epoch) if isinstance(epoch, int) else None,
        options=raw.get("options") if isinstance(raw.get("options"), dict) else None,
    )


def _load_weights(model: Scotti, state: Any, path: Path) -> None:
    """Strict load with a one-line summary instead of torch's many-line error."""
    if not isinstance(state, dict):
        msg = f"{path}: 'model' is not a state_dict"
        raise ExportError(msg)
    expected = model.state_dict()
    logits = next(k for k in reversed(expected) if k.startswith("action_head.") and "weight" in k)
    got = state.get(logits)
    if isinstance(got, torch.Tensor) and got.ndim == 2 and got.shape[0] != contract.NUM_ACTIONS:
        msg = (
            f"{path}: the action head has {got.shape[0]} logits, contract version "
            f"{contract.CONTRACT_VERSION} needs {contract.NUM_ACTIONS} "
            f"({', '.join(contract.ACTIONS)}): train it again with this version"
        )
        raise ExportError(msg)
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    wrong = sorted(
        k
        for k in set(expected) & set(state)
        if not isinstance(state[k], torch.Tensor) or state[k].shape != expected[k].shape
    )
    if missing or unexpected or wrong:
        parts = [
            f"{label} {len(names)} ({', '.join(names[:3])}{', ...' if len(names) > 3 else ''})"
            for label, names in (
                ("missing", missing),
                ("unexpected", unexpected),
                ("wrong shape", wrong),
            )
            if names
        ]
        msg = f"{path}: weights do not fit the config: {'; '.join(parts)}"
        raise ExportError(msg)
    model.load_state_dict(state)


@contextlib.contextmanager
def _quiet_exporter() -> Iterator[None]:
    """Silence the exporter's own deprecation chatter (tests run with warnings as errors)."""
    registration = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registration.level
    registration.setLevel(logging.ERROR)  # "torchvision is not installed" lines
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=FutureWarning)
            warnings.filterwarnings("ignore", category=DeprecationWarning)
            warnings.filterwarnings("ignore", message=".*axis name.*will not be used.*")
            yield
    finally:
        registration.setLevel(level)


def export_graph(
    module: nn.Module,
    example: tuple[torch.Tensor, ...],
    path: Path,
    input_names: tuple[str, ...],
    output_names: tuple[str, ...],
) -> None:
    """Dynamo export with a dynamic batch axis on every input, weights inside the file."""
    batch = torch.export.Dim("batch")
    dynamic = {name: {0: batch} for name in input_names}
    with _quiet_exporter(), torch.no_grad():
        try:
            program = torch.onnx.export(
                module.eval(),
                example,
                dynamo=True,
                opset_version=OPSET,
                input_names=list(input_names),
                output_names=list(output_names),
                dynamic_shapes=dynamic,
                external_data=False,
                verbose=False,
            )
        except Exception as exc:  # the exporter's errors are long; keep the first line
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            msg = f"ONNX export of {path.name} failed: {first}"
            raise ExportError(msg) from None
    if program is None:
        msg = f"ONNX export of {path.name} returned nothing"
        raise ExportError(msg)
    path.parent.mkdir(parents=True, exist_ok=True)
    program.save(str(path), external_data=False)


def write_metadata(
    path: Path,
    graph: str,
    cfg: ScottiConfig,
    card: dict[str, Any],
    ood: OodStats | None = None,
    progress: ProgressCalibration | None = None,
) -> None:
    """Set the contract's metadata_props (contract.META_*) on a saved graph."""
    proto = onnx.load(str(path))
    values = {
        contract.META_CONTRACT_VERSION: str(contract.CONTRACT_VERSION),
        contract.META_GRAPH: graph,
        contract.META_WINDOW: str(cfg.window),
        contract.META_EMBED_DIM: str(cfg.embed_dim),
        contract.META_FRAME_ROWS: str(cfg.rows),
        contract.META_FRAME_COLS: str(cfg.cols),
        contract.META_KEYPOINTS: json.dumps(list(contract.KEYPOINTS)),
        contract.META_ACTIONS: json.dumps(list(contract.ACTIONS)),
        contract.META_CARD: json.dumps(card, sort_keys=True, default=jsonable),
    }
    if ood is not None:
        values[contract.META_OOD] = ood.to_json()
    if progress is not None:
        values[contract.META_PROGRESS_CALIBRATION] = progress.to_json()
    if cfg.arch != "paper":  # what kind of step graph and cache (models/kv_streaming.py)
        values.update(kv_metadata(cfg))
    del proto.metadata_props[:]
    for key, value in values.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.producer_name = "scotti.export"
    onnx.save(proto, str(path))


def base_card(ckpt: Checkpoint, name: str, precision: str) -> dict[str, Any]:
    """The card embedded in every graph (no file hashes: a file cannot hash itself)."""
    cfg, top = ckpt.model.cfg, contract.MAX_COUNT
    return {
        "name": name,
        "model": "SCOTTI (Han et al.): per-frame CNN + transformer, 3 heads",
        "contract_version": contract.CONTRACT_VERSION,
        "precision": precision,
        "config": cfg.to_dict(),
        "parameters": ckpt.model.num_parameters(),
        "normalisation": f"log1p(clamp(counts, 0, {top})) / log1p({top})",
        "timing": "frames t-T..t-1 predict time t",
        "training_data": ckpt.training_data,
        "metrics": ckpt.metrics,
        "epoch": ckpt.epoch,
        "exported_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "tools": tool_versions(),
    }


def export_model(
    ckpt: Checkpoint,
    out: Path,
    *,
    int8: bool = False,
    threads: int = 1,
    tol: Tolerance = FP32,
    calibration: Calibration | None = None,
) -> ExportResult:
    """Export, prove and card one model; files appear under ``out``'s names only if proven.

    With ``calibration``, the unfamiliar score's statistics are fitted on the proven
    window graph and go into both graphs' metadata (``contract.META_OOD``) and the card.
    """
    paths = GraphPaths.for_output(out)
    model, cfg = ckpt.model.eval(), ckpt.model.cfg
    kv = cfg.arch == "streaming"
    if kv and int8:
        msg = "--int8 is not built for the streaming-native form yet (docs/streaming-native.md)"
        raise ExportError(msg)
    step_kind = KV_GRAPH if kv else "step"
    # Subnormal weights would slow every call of a runtime that keeps them (subnormals.py).
    zeroed = zero_subnormal_weights(model)
    sets = gather(ckpt.training_data, calibration) if calibration is not None else None
    if calibration is not None and calibration.as_trained:
        calibration = replace(calibration, draws=InputDraws.from_options(ckpt.options))
    name = out.with_suffix("").name
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{name}.", dir=out.parent) as tmp:
        staged = GraphPaths.for_output(Path(tmp) / out.name)
        gen = torch.Generator().manual_seed(0)
        top = float(contract.MAX_COUNT)
        frame = torch.rand(2, *cfg.frame_shape, generator=gen) * top  # (B, H, 2W)
        past = torch.randn(2, cfg.window - 1, cfg.embed_dim, generator=gen)  # (B, T-1, E)
        frames = torch.rand(2, cfg.window, *cfg.frame_shape, generator=gen) * top  # (B, T, H, 2W)
        if kv:
            step_io = (KV_STEP_INPUTS, KV_STEP_OUTPUTS)
            export_graph(KvStepGraph(model), step_example(cfg), staged.step, *step_io)
        else:
            export_graph(StepGraph(model), (frame, past), staged.step, STEP_INPUTS, STEP_OUTPUTS)
        export_graph(WindowGraph(model), (frames,), staged.window, WINDOW_INPUTS, WINDOW_OUTPUTS)
        card = {**base_card(ckpt, name, "fp32"), "subnormal_weights_zeroed": zeroed}
        write_metadata(staged.step, step_kind, cfg, card)
        write_metadata(staged.window, "window", cfg, card)
        if kv:
            parity = prove_kv(model, staged.step, staged.window, threads, tol)
        else:
            parity = prove(model, staged.step, staged.window, threads, tol)
        ood, progress = None, None
        if calibration is not None and sets is not None:
            ood = calibrate(staged.window, sets, calibration, threads)
            progress = fit_progress(staged.window, sets.held_out, calibration, threads)
            card = {**card, "ood": ood_card(ood), "progress_calibration": progress_card(progress)}
            write_metadata(staged.step, step_kind, cfg, card, ood, progress)
            write_metadata(staged.window, "window", cfg, card, ood, progress)
        else:
            card = {**card, "ood": {"calibrated": False}}
        files = {"step": file_entry(staged.step), "window": file_entry(staged.window)}
        int8_drift: Report = {}
        int8_ood = None
        if int8:
            int8_card = {**card, "precision": "int8 dynamic (MatMul/Gemm weights), Conv fp32"}
            graphs = (
                (staged.step, staged.int8_step, "step"),
                (staged.window, staged.int8_window, "window"),
            )
            for src, dst, _ in graphs:
                quantize_int8(src, dst)
            if calibration is not None and sets is not None:
                # int8 moves the pooled vector: with the fp32 statistics a p2 partition
                # model's int8 graph flagged 1.26 % of its validation windows instead of
                # 1 % (docs/accuracy-vs-latency.md), so the int8 graphs get their own.
                # The progress map stays the fp32 one: int8 moved progress MSE by 2e-5.
                int8_ood = calibrate(staged.int8_window, sets, calibration, threads)
                int8_card = {**int8_card, "ood": ood_card(int8_ood)}
            for _, dst, graph in graphs:
                write_metadata(dst, graph, cfg, int8_card, int8_ood or ood, progress)
            int8_drift = drift(
                cfg, (staged.step, staged.window), (staged.int8_step, staged.int8_window), threads
            )
            files["int8_step"] = file_entry(staged.int8_step)
            files["int8_window"] = file_entry(staged.int8_window)
        full_card = {
            **card,
            "files": files,
            "parity": {"tolerance": {"atol": tol.atol, "rtol": tol.rtol}, "max_abs_diff": parity},
            "int8_drift_max_abs": int8_drift or None,
        }
        if int8_ood is not None:
            full_card["int8_ood"] = ood_card(int8_ood)
        text = json.dumps(full_card, indent=2, sort_keys=True, default=jsonable)
        staged.card_json.write_text(text + "\n")
        staged.card_md.write_text(card_markdown(full_card))
        for kind in ("step", "window", "card_json", "card_md", "int8_step", "int8_window"):
            src = getattr(staged, kind)
            if src.exists():
                os.replace(src, getattr(paths, kind))
        if not int8:  # an earlier export's int8 copies would pass for this model's
            for stale in paths.int8():
                stale.unlink(missing_ok=True)
    return ExportResult(paths=paths, card=full_card, parity=parity, int8_drift=int8_drift)


def progress_card(progress: ProgressCalibration | None) -> dict[str, Any]:
    """The card's progress calibration section: what it was fitted on, or why none."""
    if progress is None:
        return {"calibrated": False, "reason": "no action predicted on enough held-out windows"}
    return {"calibrated": True, **progress.summary}


def ood_card(ood: OodStats) -> dict[str, Any]:
    """The card's OOD section: the statistics' summary and the input checks' thresholds."""
    return {"calibrated": True, **ood.summary, "input_checks": input_check_thresholds()}


def export_checkpoint(
    checkpoint: Path,
    out: Path,
    *,
    int8: bool = False,
    threads: int = 1,
    calibration: Calibration | None = None,
) -> ExportResult:
    return export_model(
        load_checkpoint(checkpoint), out, int8=int8, threads=threads, calibration=calibration
    )
