"""A torch checkpoint rebuilt from a shipped model's graph, checked on a real session's windows.

    python experiments/checkpoint_from_onnx.py models/scotti-default.onnx \
        -o runs/default-p1/base.pt --check data/corpus7/realistic/subject-011.ses

``scotti train --init NAME.onnx`` does the same rebuild on the fly
(export/graph_weights.py, checked on seeded random windows); this writes the
checkpoint to a file and checks it on windows of a real session too, printing
the largest difference of each output. Nothing is written if any output
differs by more than export/graph_weights.py's tolerance.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def session_windows(session: Path, window: int, count: int = 64) -> np.ndarray:
    """(count, T, H, 2W) float32 counts: windows spread over the session."""
    from scotti.export.data import load_session

    frames = load_session(session).frames
    starts = np.linspace(0, len(frames) - window, count).astype(int)
    return np.stack([frames[s : s + window] for s in starts]).astype(np.float32)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("graph", type=Path, help="NAME.onnx or NAME.window.onnx")
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--check", type=Path, help="a session file whose windows both run on")
    args = ap.parse_args(argv)
    from scotti.export.checkpoint import save_checkpoint
    from scotti.export.graph_weights import GraphWeightsError, checkpoint_from_graph

    try:
        ckpt = checkpoint_from_graph(args.graph)  # seeded random windows
        if args.check is not None:
            frames = session_windows(args.check, ckpt["config"]["window"])
            ckpt = checkpoint_from_graph(args.graph, frames)
    except GraphWeightsError as exc:
        print(f"checkpoint_from_onnx: {exc}", file=sys.stderr)
        return 1
    diffs = ckpt["parity"]
    print("largest |torch - graph|: " + ", ".join(f"{k} {v:.2e}" for k, v in diffs.items()))
    save_checkpoint(ckpt, args.output)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
