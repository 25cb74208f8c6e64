"""Opening an exported SCOTTI graph and checking it against the contract.

What ``ScottiRuntime`` (models/runtime.py) does before it runs anything: read
the file (and its sha256, which the daemon publishes), open an onnxruntime
session, and refuse with a one-line ``ModelContractError`` any metadata,
input or output that does not fit ``contract.py``; then read the optional
``scotti.ood`` statistics the ``unfamiliar`` score needs.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import onnxruntime as ort
from scotti.models import contract as c
from scotti.models.errors import ModelContractError, ModelError
from scotti.models.ood import OodStats
from scotti.models.subnormal_weights import without_subnormal_weights

_FLOAT = "tensor(float)"
_REQUIRED_META = (
    c.META_CONTRACT_VERSION,
    c.META_GRAPH,
    c.META_WINDOW,
    c.META_EMBED_DIM,
    c.META_FRAME_ROWS,
    c.META_FRAME_COLS,
    c.META_KEYPOINTS,
    c.META_ACTIONS,
)


def sha256_of(path: Path) -> str:
    try:
        with path.open("rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
    except FileNotFoundError:
        msg = f"model file {path} does not exist"
        raise ModelError(msg) from None
    except OSError as exc:
        msg = f"cannot read model file {path}: {exc.strerror or exc}"
        raise ModelError(msg) from None


def open_session(path: Path, threads: int) -> ort.InferenceSession:
    # Off before any session exists: a robot's host sends nothing about its model
    # anywhere (onnxruntime's telemetry events; its builds for Windows emit them).
    ort.disable_telemetry_events()
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.log_severity_level = 3  # errors only: warnings would go to the daemon's stderr
    if threads > 1:
        # Spinning workers burn the cores the serial reader and a second session need:
        # two chained sessions with spinning doubled the step time on a small host.
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    zeroed = without_subnormal_weights(path)  # what they would cost: subnormal_weights.py
    source: str | bytes = zeroed[0] if zeroed is not None else str(path)
    try:
        return ort.InferenceSession(source, options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own unexported exception types
        # "[ONNXRuntimeError] : 7 : INVALID_PROTOBUF : Load model from P failed:Protobuf ..."
        lines = str(exc).strip().splitlines() or [type(exc).__name__]
        reason = lines[-1].rpartition("failed:")[2].strip() or lines[-1]
        msg = f"{path} is not a loadable ONNX model ({reason})"
        raise ModelError(msg) from None


def check_metadata(meta: dict[str, str]) -> tuple[str, int, int, dict[str, Any]]:
    """(graph, T, E, card) from the metadata, or ModelContractError naming the misfit."""
    if not any(key.startswith("scotti.") for key in meta):
        msg = "model carries no scotti.* metadata: not a SCOTTI export"
        raise ModelContractError(msg)
    for key in _REQUIRED_META:
        if key not in meta:
            msg = f"model metadata lacks {key}"
            raise ModelContractError(msg)
    version = meta[c.META_CONTRACT_VERSION]
    if version != str(c.CONTRACT_VERSION):
        msg = (
            f"model has contract version {version}, this runtime needs {c.CONTRACT_VERSION} "
            f"(export one with this version of scotti)"
        )
        raise ModelContractError(msg)
    graph = meta[c.META_GRAPH]
    if graph not in ("step", "window"):
        msg = f"model graph kind is {graph!r}, the contract knows 'step' and 'window'"
        raise ModelContractError(msg)
    window = _meta_int(meta, c.META_WINDOW)
    if window != c.WINDOW:
        msg = f"model has window T={window}, contract needs {c.WINDOW}"
        raise ModelContractError(msg)
    rows, cols = _meta_int(meta, c.META_FRAME_ROWS), _meta_int(meta, c.META_FRAME_COLS)
    if (rows, cols) != (c.FRAME_ROWS, c.FRAME_COLS):
        msg = (
            f"model frame is {rows}x{cols} taxels per foot, "
            f"contract needs {c.FRAME_ROWS}x{c.FRAME_COLS}"
        )
        raise ModelContractError(msg)
    _check_names(meta, c.META_KEYPOINTS, "keypoint", c.KEYPOINTS)
    _check_names(meta, c.META_ACTIONS, "action", c.ACTIONS)
    embed_dim = _meta_int(meta, c.META_EMBED_DIM)
    card = _meta_card(meta)
    return graph, window, embed_dim, card


def _meta_int(meta: dict[str, str], key: str) -> int:
    try:
        value = int(meta[key])
    except ValueError:
        value = 0
    if value < 1:
        msg = f"model metadata {key} is {meta[key]!r}, not a positive integer"
        raise ModelContractError(msg)
    return value


def _check_names(meta: dict[str, str], key: str, what: str, expected: tuple[str, ...]) -> None:
    try:
        names = json.loads(meta[key])
    except json.JSONDecodeError:
        names = None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        msg = f"model metadata {key} is not a JSON list of names"
        raise ModelContractError(msg)
    if len(names) != len(expected):
        msg = f"model has {len(names)} {what}s, contract needs {len(expected)}"
        raise ModelContractError(msg)
    for i, (got, want) in enumerate(zip(names, expected, strict=True)):
        if got != want:
            msg = f"model {what} {i} is {got!r}, contract needs {want!r}"
            raise ModelContractError(msg)


def _meta_card(meta: dict[str, str]) -> dict[str, Any]:
    if c.META_CARD not in meta:
        return {}
    try:
        card = json.loads(meta[c.META_CARD])
    except json.JSONDecodeError:
        card = None
    if not isinstance(card, dict):
        msg = f"model metadata {c.META_CARD} is not a JSON object"
        raise ModelContractError(msg)
    return card


def ood_stats(meta: dict[str, str], embed_dim: int, has_pooled: bool) -> OodStats | None:
    if c.META_OOD not in meta:
        return None
    if not has_pooled:
        msg = f"model carries {c.META_OOD} statistics but no {c.OUTPUT_POOLED!r} output"
        raise ModelContractError(msg)
    return OodStats.from_json(meta[c.META_OOD], embed_dim)


def _expected_io(
    graph: str, window: int, embed_dim: int
) -> tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
    """Input and output shapes without the batch dimension."""
    frame: tuple[int, ...] = (c.FRAME_ROWS, 2 * c.FRAME_COLS)
    outputs = {
        c.OUTPUT_POSE: (c.NUM_KEYPOINTS, 3),
        c.OUTPUT_ACTION_LOGITS: (c.NUM_ACTIONS,),
        c.OUTPUT_PROGRESS: (),
    }
    if graph == "window":
        return {c.WINDOW_INPUT_FRAMES: (window, *frame)}, outputs
    inputs = {c.STEP_INPUT_FRAME: frame, c.STEP_INPUT_PAST: (window - 1, embed_dim)}
    return inputs, {**outputs, c.STEP_OUTPUT_EMBEDDING: (embed_dim,)}


def check_io(session: ort.InferenceSession, graph: str, window: int, embed_dim: int) -> bool:
    """Checks inputs and outputs; returns whether the graph has the optional pooled output."""
    want_in, want_out = _expected_io(graph, window, embed_dim)
    have_in = {arg.name: arg for arg in session.get_inputs()}
    have_out = {arg.name: arg for arg in session.get_outputs()}
    if set(have_in) != set(want_in):
        msg = f"model inputs are {sorted(have_in)}, a {graph} graph needs {sorted(want_in)}"
        raise ModelContractError(msg)
    for name in want_out:
        if name not in have_out:
            msg = f"model lacks output {name!r} that a {graph} graph needs"
            raise ModelContractError(msg)
    has_pooled = c.OUTPUT_POOLED in have_out
    if has_pooled:
        want_out = {**want_out, c.OUTPUT_POOLED: (embed_dim,)}
    for kind, have, want in (("input", have_in, want_in), ("output", have_out, want_out)):
        for name, shape in want.items():
            _check_arg(kind, name, have[name].type, list(have[name].shape), shape)
    return has_pooled


def _check_arg(kind: str, name: str, dtype: str, dims: list[Any], want: tuple[int, ...]) -> None:
    """Batch dimension free; any other fixed size must be the contract's (symbols pass)."""
    if dtype != _FLOAT:
        msg = f"model {kind} {name!r} is {dtype}, contract needs {_FLOAT}"
        raise ModelContractError(msg)
    fits = len(dims) == len(want) + 1 and all(
        not isinstance(d, int) or d == w for d, w in zip(dims[1:], want, strict=True)
    )
    if not fits:
        shown = ", ".join(str(d) for d in dims)
        needed = ", ".join(["B", *map(str, want)])
        msg = f"model {kind} {name!r} has shape ({shown}), contract needs ({needed})"
        raise ModelContractError(msg)
