"""How much history the streaming-native form's figures depend on.

``python experiments/streaming_native_history.py RUN_DIR/best.pt SESSION... [--chunks 1 8 64 512]``

The streaming-native form (docs/streaming-native.md) reads the last T + layers (T-1)
frames in steady streaming, but a training window of T frames is a stream started
at its first frame. ``scotti train`` evaluates windows in chunks of consecutive
windows run as one stream (``export/evaluate.py``), so a window's history is what
its chunk gives it. This scores the same windows (stride ``--stride``) with chunks
of 1 window (no history: what the window graph and ``scotti eval``'s window path
compute), the validation's 64, and longer ones (nearly all windows in steady state,
as the daemon's step graph runs). A paper-form checkpoint gives the same figures at
every chunk length (its window is all it reads), which makes it a control.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import torch
from scotti.export import evaluate
from scotti.export.onnx_export import load_checkpoint
from scotti.export.run_data import load_sessions
from scotti.export.windows import WindowDataset

KEYS = ("mpjpe_mm", "mpjae_deg", "action_accuracy", "progress_mse", "app")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="streaming_native_history")
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("sessions", type=Path, nargs="+")
    parser.add_argument("--chunks", type=int, nargs="+", default=[1, 8, 64, 512])
    parser.add_argument("--stride", type=int, default=4)
    parser.add_argument("--cache", type=Path, default=Path("runs/.session-cache"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    model = load_checkpoint(args.checkpoint).model
    data = WindowDataset(load_sessions(args.sessions, args.cache), model.cfg.window)
    print(f"{args.checkpoint} ({model.cfg.arch} form), {data.count(args.stride)} windows")
    print("| windows per chunk | " + " | ".join(KEYS) + " |")
    print("|---" * (len(KEYS) + 1) + "|")
    for chunk in args.chunks:
        evaluate.EVAL_CHUNK = chunk  # the evaluation's own chunk length, this run only
        m = evaluate.evaluate(model, data, args.stride)
        print(f"| {chunk} | " + " | ".join(f"{m[k]:.4g}" for k in KEYS) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
