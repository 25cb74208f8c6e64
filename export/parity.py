"""Proof that an exported graph computes what the torch model computes.

Three checks on the same inputs, hard ones included (STYLE.md point 10):
the window graph against torch, the step graph against torch, and the step
graph fed a sequence frame by frame (its own embeddings as the cache) against
the window graph on the same T frames. Each check reports the max abs
difference per output; a value beyond ``Tolerance`` raises ``ParityError``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from scotti.export.errors import ExportError, ParityError
from scotti.export.model import Scotti, ScottiConfig
from scotti.models import contract

Arrays = dict[str, np.ndarray]
Report = dict[str, dict[str, float]]  # check -> output -> max abs difference

U16_MAX = 0xFFFF  # what a corrupt 16-bit sample on the wire could carry

# Graph I/O names in the order the graphs declare them (contract.py names).
STEP_INPUTS = (contract.STEP_INPUT_FRAME, contract.STEP_INPUT_PAST)
WINDOW_INPUTS = (contract.WINDOW_INPUT_FRAMES,)
HEAD_OUTPUTS = (contract.OUTPUT_POSE, contract.OUTPUT_ACTION_LOGITS, contract.OUTPUT_PROGRESS)
# The pooled representation comes last in both graphs (the existing outputs keep their places).
WINDOW_OUTPUTS = (*HEAD_OUTPUTS, contract.OUTPUT_POOLED)
STEP_OUTPUTS = (*HEAD_OUTPUTS, contract.STEP_OUTPUT_EMBEDDING, contract.OUTPUT_POOLED)


@dataclass(frozen=True)
class Tolerance:
    """|onnx - reference| <= atol + rtol * |reference|, elementwise."""

    atol: float = 1e-4
    rtol: float = 1e-4


FP32 = Tolerance()


def session(path: Path, threads: int = 1) -> ort.InferenceSession:
    """A CPU session that does not spin (two sessions side by side stay fair)."""
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def hard_windows(cfg: ScottiConfig, seed: int = 0) -> dict[str, np.ndarray]:
    """Named windows (T, H, 2W) float32 of raw counts that have broken models before."""
    rng = np.random.default_rng(seed)
    shape = (cfg.window, *cfg.frame_shape)
    top = float(contract.MAX_COUNT)
    hot = np.zeros(shape, np.float32)
    hot[:, cfg.rows // 3, cfg.cols + 3] = top  # one taxel at the largest count allowed
    windows = {
        "random": rng.uniform(0, top, shape),
        "zeros": np.zeros(shape),  # both feet in the air: flight phase of a jump
        "saturated": np.full(shape, top),  # every taxel at MAX_COUNT
        "hot_taxel": hot,
        "beyond_protocol": np.full(shape, float(U16_MAX)),  # clamped inside the graph
    }
    mixed = rng.uniform(0, top, shape)
    mixed[0::4] = 0.0
    mixed[1::4] = top
    mixed[2::4] = hot[0]
    windows["mixed"] = mixed
    return {k: v.astype(np.float32) for k, v in windows.items()}


def stream_sequence(cfg: ScottiConfig, length: int, seed: int = 1) -> np.ndarray:
    """(length, H, 2W) frames: random contact with flights, saturation and a hot taxel."""
    rng = np.random.default_rng(seed)
    frames = rng.uniform(0, contract.MAX_COUNT, (length, *cfg.frame_shape)).astype(np.float32)
    frames[5:9] = 0.0
    frames[cfg.window // 2] = contract.MAX_COUNT
    frames[cfg.window + 1] = U16_MAX
    frames[-3:, :, :] = 0.0
    frames[-3:, 2, 2] = contract.MAX_COUNT
    return frames


def run(sess: ort.InferenceSession, feeds: Arrays) -> Arrays:
    names = [o.name for o in sess.get_outputs()]
    return dict(zip(names, sess.run(names, feeds), strict=True))


def max_abs(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)), initial=0.0))


def _compare(got: Arrays, want: Arrays, tol: Tolerance, check: str) -> dict[str, float]:
    diffs = {}
    for name, ref in want.items():
        if got[name].shape != ref.shape:
            msg = f"{check}: {name} has shape {got[name].shape}, expected {ref.shape}"
            raise ParityError(msg)
        diffs[name] = max_abs(got[name], ref)
        if not np.allclose(got[name], ref, atol=tol.atol, rtol=tol.rtol):
            msg = (
                f"{check}: {name} differs by {diffs[name]:.3g} "
                f"(tolerance atol {tol.atol:g} + rtol {tol.rtol:g})"
            )
            raise ParityError(msg)
    return diffs


def check_sane(out: Arrays, where: str) -> None:
    """Finite outputs, progress within [0, 1], action probabilities summing to 1."""
    for name, value in out.items():
        if not np.isfinite(value).all():
            msg = f"{where}: {name} is not finite"
            raise ExportError(msg)
    progress = out[contract.OUTPUT_PROGRESS]
    if ((progress < 0) | (progress > 1)).any():
        msg = f"{where}: progress outside [0, 1]: {progress.min():g}..{progress.max():g}"
        raise ExportError(msg)
    logits = out[contract.OUTPUT_ACTION_LOGITS].astype(np.float64)
    probs = np.exp(logits - logits.max(axis=-1, keepdims=True))
    sums = (probs / probs.sum(axis=-1, keepdims=True)).sum(axis=-1)
    if not np.allclose(sums, 1.0, atol=1e-6):
        msg = f"{where}: action probabilities do not sum to 1"
        raise ExportError(msg)


def check_structure(path: Path, graph: str) -> None:
    """onnx.checker plus the contract's input and output names."""
    try:
        onnx.checker.check_model(str(path), full_check=True)
    except Exception as exc:  # checker errors are many types and many lines
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        msg = f"{path.name}: ONNX checker: {first}"
        raise ExportError(msg) from None
    proto = onnx.load(str(path), load_external_data=False)
    inputs = [i.name for i in proto.graph.input]
    outputs = [o.name for o in proto.graph.output]
    if graph == "step":
        want_in, want_out = list(STEP_INPUTS), list(STEP_OUTPUTS)
    else:
        want_in, want_out = list(WINDOW_INPUTS), list(WINDOW_OUTPUTS)
    if inputs != want_in or outputs != want_out:
        msg = f"{path.name}: I/O {inputs} -> {outputs}, contract wants {want_in} -> {want_out}"
        raise ExportError(msg)


def torch_window(model: Scotti, frames: np.ndarray) -> Arrays:
    """The window graph's outputs computed by torch: the three heads and the pooled vector."""
    b, t = frames.shape[:2]
    with torch.no_grad():
        emb = model.eval().embed_frames(torch.from_numpy(frames.reshape(b * t, *frames.shape[2:])))
        heads, pooled = model.forward_embeddings_pooled(emb.view(b, t, -1))
    out = {n: x.numpy() for n, x in zip(HEAD_OUTPUTS, heads, strict=True)}
    return {**out, contract.OUTPUT_POOLED: pooled.numpy()}


def stream(step: ort.InferenceSession, frames: np.ndarray, embed_dim: int, window: int) -> Arrays:
    """Feed (S, H, 2W) frames one at a time, the cache built from the step's own outputs.

    Returns per-step outputs stacked over S (the cache starts as zeros, so only
    steps from T-1 on see a full window).
    """
    past = np.zeros((1, window - 1, embed_dim), np.float32)
    steps: list[Arrays] = []
    for frame in frames:
        out = run(step, {contract.STEP_INPUT_FRAME: frame[None], contract.STEP_INPUT_PAST: past})
        past = np.concatenate([past[:, 1:], out[contract.STEP_OUTPUT_EMBEDDING][:, None]], axis=1)
        steps.append(out)
    return {k: np.concatenate([s[k] for s in steps]) for k in steps[0]}


def sliding_windows(frames: np.ndarray, window: int) -> np.ndarray:
    """(S, H, 2W) -> (S-T+1, T, H, 2W): every full window, oldest frame first."""
    return np.stack([frames[i - window + 1 : i + 1] for i in range(window - 1, len(frames))])


def prove(
    model: Scotti, step_path: Path, window_path: Path, threads: int = 1, tol: Tolerance = FP32
) -> Report:
    """All checks on an fp32 export; returns the max abs differences it measured."""
    cfg = model.cfg
    check_structure(step_path, "step")
    check_structure(window_path, "window")
    step, win = session(step_path, threads), session(window_path, threads)
    frames = np.stack(list(hard_windows(cfg).values()))  # (B, T, H, 2W)
    report: Report = {}

    want = torch_window(model, frames)
    got = run(win, {contract.WINDOW_INPUT_FRAMES: frames})
    check_sane(got, "window graph")
    report["window_vs_torch"] = _compare(got, want, tol, "window graph vs torch")

    with torch.no_grad():
        b, t = frames.shape[:2]
        emb = model.embed_frames(torch.from_numpy(frames.reshape(b * t, *cfg.frame_shape)))
        emb_np = emb.view(b, t, -1).numpy()
    want_step = {**want, contract.STEP_OUTPUT_EMBEDDING: emb_np[:, -1]}
    feeds = {contract.STEP_INPUT_FRAME: frames[:, -1], contract.STEP_INPUT_PAST: emb_np[:, :-1]}
    got = run(step, feeds)
    check_sane(got, "step graph")
    report["step_vs_torch"] = _compare(got, want_step, tol, "step graph vs torch")

    seq = stream_sequence(cfg, 2 * cfg.window)
    streamed = stream(step, seq, cfg.embed_dim, cfg.window)
    check_sane(streamed, "streamed steps")
    full = {k: v[cfg.window - 1 :] for k, v in streamed.items() if k in WINDOW_OUTPUTS}
    windowed = run(win, {contract.WINDOW_INPUT_FRAMES: sliding_windows(seq, cfg.window)})
    report["stream_vs_window"] = _compare(full, windowed, tol, "streamed step vs window graph")
    return report


def drift(
    cfg: ScottiConfig, fp32: tuple[Path, Path], int8: tuple[Path, Path], threads: int = 1
) -> Report:
    """Max abs difference int8 vs fp32 per output: measured and reported, not judged.

    Only structure, shapes and sanity (finite, progress in [0, 1]) must hold.
    """
    check_structure(int8[0], "step")
    check_structure(int8[1], "window")
    frames = np.stack(list(hard_windows(cfg).values()))
    report: Report = {}
    ref = run(session(fp32[1], threads), {contract.WINDOW_INPUT_FRAMES: frames})
    got = run(session(int8[1], threads), {contract.WINDOW_INPUT_FRAMES: frames})
    check_sane(got, "int8 window graph")
    report["int8_window_vs_fp32"] = _shape_checked_diffs(got, ref)
    seq = stream_sequence(cfg, 2 * cfg.window)
    ref = stream(session(fp32[0], threads), seq, cfg.embed_dim, cfg.window)
    got = stream(session(int8[0], threads), seq, cfg.embed_dim, cfg.window)
    check_sane(got, "int8 streamed steps")
    report["int8_stream_vs_fp32"] = _shape_checked_diffs(got, ref)
    return report


def _shape_checked_diffs(got: Arrays, ref: Arrays) -> dict[str, float]:
    for name, value in ref.items():
        if got[name].shape != value.shape:
            msg = f"int8 {name} has shape {got[name].shape}, fp32 has {value.shape}"
            raise ExportError(msg)
    return {name: max_abs(got[name], value) for name, value in ref.items()}


def format_report(report: Report) -> list[str]:
    """One line per check: 'check: output=diff, ...'."""
    return [
        f"{check}: " + ", ".join(f"{name} {diff:.2e}" for name, diff in diffs.items())
        for check, diffs in report.items()
    ]
