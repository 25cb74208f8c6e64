"""What the first step of a fine-tune trains: a model's training pass beside its inference.

    python experiments/norm_statistics.py [--model models/scotti-default.onnx] \\
        [--checkpoint runs/NAME/best.pt ...] [--sessions data/corpus21/realistic] [--chunks 16]

An exported graph has its frame CNN's batch norm folded into the projection
(export/graph_weights.py): read back, the norm is the identity. A training
pass with batch statistics standardises the projection's output again, so
the model a fine-tune starts from is not the graph. For chunks of corpus
sessions as training builds them (stride 10, 8 windows a chunk), this prints
how far the pooled vectors the heads read (relative squared distance,
export/anchor.py) and the action taken move from inference (eval mode) to a
training pass without dropout, with the norm on batch statistics and with it
kept (``scotti train --norm-statistics``). For a ``--checkpoint`` it also
prints how far its inference is from the ``--model``'s: what a fine-tune moved.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT

STRIDE, CHUNK = 10, 8  # scripts/train_wide.sh's recipe


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "scotti-default.onnx")
    parser.add_argument("--checkpoint", type=Path, action="append", default=[])
    parser.add_argument("--sessions", type=Path, default=ROOT / "data/corpus21/realistic")
    parser.add_argument("--files", type=int, default=3, help="sessions read from --sessions")
    parser.add_argument("--chunks", type=int, default=16)
    args = parser.parse_args(argv)

    import torch
    from scotti.export.anchor import relative_distance
    from scotti.export.checkpoint import load_checkpoint
    from scotti.export.data import load_session
    from scotti.export.evaluate import chunked_outputs_pooled
    from scotti.export.finetune import load_initial_weights
    from scotti.export.graph_weights import checkpoint_from_graph
    from scotti.export.model import Scotti, ScottiConfig
    from scotti.export.windows import WindowDataset

    init = checkpoint_from_graph(args.model)
    cfg = ScottiConfig.from_dict(init["config"])
    files = sorted(args.sessions.glob("*.ses"))[: args.files]
    if not files:
        print(f"no .ses files in {args.sessions}", file=sys.stderr)
        return 2
    data = WindowDataset([load_session(f) for f in files], window=cfg.window)
    chunks = list(data.chunks(stride=STRIDE, chunk=CHUNK))
    picked = np.random.default_rng(0).choice(len(chunks), min(args.chunks, len(chunks)), False)
    frames = [torch.from_numpy(data.frames(chunks[i]).astype(np.float32)) for i in picked]

    def run(model: Scotti, train: bool, kept: bool) -> tuple[torch.Tensor, torch.Tensor]:
        model.train(train)
        for module in model.modules():
            if isinstance(module, torch.nn.Dropout):
                module.eval()  # dropout off: only the norm differs between the passes
        if kept:
            model.cnn.norm.eval()
        state = {k: b.clone() for k, b in model.named_buffers()}
        with torch.no_grad():
            outputs, pooled = chunked_outputs_pooled(model, frames, cfg.window, STRIDE)
        model.load_state_dict(state, strict=False)  # running statistics as they were
        return outputs.action_logits.argmax(-1), pooled

    graph = Scotti(cfg)
    load_initial_weights(graph, init["model"])
    action, pooled = run(graph, train=False, kept=False)
    print(f"{args.model.name}, {len(frames)} chunks of {len(files)} sessions in {args.sessions}:")
    for name, kept in (("batch", False), ("kept", True)):
        a, p = run(graph, train=True, kept=kept)
        print(
            f"  training pass, norm on {name} statistics: pooled vectors "
            f"{float(relative_distance(p, pooled)):.4f} from inference, "
            f"same action on {float((a == action).float().mean()):.1%} of windows"
        )
    for path in args.checkpoint:
        tuned = Scotti(cfg)
        tuned.load_state_dict(load_checkpoint(path)["model"])
        a, p = run(tuned, train=False, kept=False)
        print(
            f"  {path}: inference {float(relative_distance(p, pooled)):.4f} from the graph's, "
            f"same action on {float((a == action).float().mean()):.1%} of windows"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
