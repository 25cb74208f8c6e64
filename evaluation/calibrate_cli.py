"""``scotti calibrate MODEL.onnx SESSIONS...``: fit the progress calibration on held-out
subjects and write it into the model (models/progress_calibration.py).

The sessions are replayed through the daemon's path with the progress head's
output as it is (``scotti eval``'s replay), a monotone map per predicted action
is fitted from output to label, and it goes into the metadata of the step
graph and of the window graph beside it (``NAME.window.onnx``), replacing any
earlier one. Either form: the paper form's step graph or the streaming-native
one's (``scotti.graph`` = ``step_kv``, models/kv_streaming.py), opened as ``scotti
eval`` and the daemon open it and replayed through that form's own step loop.
That is an edit of the model in place, not an output file written beside it,
so the tools' overwrite rule (refused unless ``--force``) does not apply: the
graphs keep their names, their weights and every other metadata entry.
Sessions of subjects the model was trained on are refused (the card names
them): a calibration fitted on training data would hide the very hedging it
is there to undo. Use the validation subjects; keep the test
subjects for ``scotti eval``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import onnx
from scotti.evaluation.errors import EvaluationError
from scotti.evaluation.frames import FrameSet
from scotti.evaluation.replay import replay_session
from scotti.firmware_protocol.errors import SessionError
from scotti.firmware_protocol.session import find_session_files
from scotti.models.contract import META_PROGRESS_CALIBRATION
from scotti.models.errors import ModelError
from scotti.models.kv_streaming import open_step_model
from scotti.models.progress_calibration import ProgressCalibration, fit
from scotti.models.runtime import ScottiRuntime, window_graph_for


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "model",
        type=Path,
        help="the step graph (.onnx, either form), edited in place with its window graph: an "
        "edit of the model, not an output file, so no --force (copy the graphs first to keep "
        "them)",
    )
    parser.add_argument("sessions", nargs="+", type=Path, help="held-out subjects' sessions")


def run(args: argparse.Namespace) -> int:
    try:
        runtime = open_step_model(args.model, calibrate_progress=False)
        if runtime.graph == "window":
            msg = f"{args.model.name} is a {runtime.graph} graph; give the step graph"
            raise EvaluationError(msg)
        files = find_session_files(args.sessions)
        replays = [replay_session(path, runtime) for path in files]
        trained_on = set(training_subjects(runtime.card))
        leaked = sorted({r.subject for r in replays} & trained_on)
        if leaked:
            msg = (
                f"{', '.join(leaked)}: the model was trained on them; calibrate on "
                "held-out (validation) subjects"
            )
            raise EvaluationError(msg)
        frames = FrameSet.concat([r.frames for r in replays])
        calibration = fit(frames.progress_pred, frames.progress_true, frames.action_pred)
        if not calibration.knots:
            msg = "too few labelled progress frames in these sessions to calibrate"
            raise EvaluationError(msg)
        calibration.summary["fitted_on"] = sorted({r.subject for r in replays})
        written = [args.model]
        write_calibration(args.model, calibration)
        window = window_graph_for(args.model)
        if window.is_file():
            write_calibration(window, calibration)
            written.append(window)
        open_step_model(args.model)  # read back as the daemon and scotti eval will
        if window in written:
            ScottiRuntime(window)
    except (EvaluationError, ModelError, SessionError, OSError) as exc:
        print(f"scotti calibrate: {exc}", file=sys.stderr)
        return 2
    s = calibration.summary
    print(
        f"progress calibration from {len(frames)} frames of {', '.join(s['fitted_on'])}: "
        f"MSE {s['mse_before']:.4f} -> {s['mse_after']:.4f} on them; "
        f"maps for {', '.join(s['frames'])}; written to {', '.join(map(str, written))}"
    )
    return 0


def training_subjects(card: dict[str, Any]) -> list[str]:
    """The subjects the card says the model was trained on ([] when it does not say)."""
    data = card.get("training_data")
    split = data.get("split") if isinstance(data, dict) else None
    subjects = split.get("train_subjects") if isinstance(split, dict) else None
    return [str(s) for s in subjects] if isinstance(subjects, list) else []


def write_calibration(path: Path, calibration: ProgressCalibration) -> None:
    """Put the calibration into a graph's metadata, every other entry kept."""
    proto = onnx.load(str(path))
    for prop in proto.metadata_props:
        if prop.key == META_PROGRESS_CALIBRATION:
            prop.value = calibration.to_json()
            break
    else:
        entry = proto.metadata_props.add()
        entry.key, entry.value = META_PROGRESS_CALIBRATION, calibration.to_json()
    tmp = path.with_name(path.name + ".tmp")
    onnx.save(proto, str(tmp))
    tmp.replace(path)  # never half a model on disk
