"""How hard ``--keep-near`` pulls against the task: gradient norms of both on real batches.

    python experiments/anchor_gradients.py --checkpoint runs/v31-keep-near/best.pt \\
        [--init models/scotti-default.onnx] [--weight 10] [--pass eval|matched] \\
        [--session data/corpus21/realistic/subject-000.ses] [--batches 5]

For the ``--init`` weights themselves and for a trained checkpoint, on a few
chunks of one session as training builds them (stride 10, 8 windows a chunk,
spread over the session): the pull's term (export/anchor.py), the norm of its
weighted gradient, the task loss (the recipe's weights 0.01, 1, 3) and the
norm of its gradient. Training clips the sum of both to a norm of 1, so where
the pull's norm is several times the task's, most of every step goes to it.
With ``--pass eval`` the trained model runs each chunk in training mode first (as
a step does), so its batch-norm statistics move as they do in training. With
``--pass matched`` the pull is read off the training pass itself, replayed by
the reference (export/anchor.py), the norm on its own statistics as a
fine-tune of a graph runs it (``--norm-statistics kept``). A few seconds on a CPU.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT

CHUNK, STRIDE = 8, 10  # scripts/train_wide.sh's recipe (scotti train's --chunk default)
LOSS_WEIGHTS = (0.01, 1.0, 3.0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--init", type=Path, default=ROOT / "models" / "scotti-default.onnx")
    parser.add_argument("--weight", type=float, default=10.0)
    parser.add_argument(
        "--session", type=Path, default=ROOT / "data/corpus21/realistic/subject-000.ses"
    )
    parser.add_argument("--batches", type=int, default=5)
    parser.add_argument("--pass", dest="pass_", choices=("eval", "matched"), default="eval")
    args = parser.parse_args(argv)

    import torch
    from scotti.export.anchor import Anchor
    from scotti.export.checkpoint import load_checkpoint
    from scotti.export.data import load_session
    from scotti.export.evaluate import chunked_outputs_pooled
    from scotti.export.finetune import load_initial_weights
    from scotti.export.graph_weights import checkpoint_from_graph
    from scotti.export.losses import LossWeights, ScottiTargets, scotti_loss
    from scotti.export.model import Scotti, ScottiConfig
    from scotti.export.rng_state import rng_state
    from scotti.export.windows import WindowDataset

    torch.manual_seed(0)
    init = checkpoint_from_graph(args.init)
    cfg = ScottiConfig.from_dict(init["config"])
    reference = Scotti(cfg)
    load_initial_weights(reference, init["model"])
    anchor = Anchor(reference, args.weight, args.pass_)
    data = WindowDataset([load_session(args.session)], window=cfg.window)
    chunks = list(data.chunks(stride=STRIDE, chunk=CHUNK))
    picked = [
        chunks[i] for i in np.linspace(0, len(chunks) - 1, args.batches + 2)[1:-1].astype(int)
    ]

    def grad_norm(model: Scotti) -> float:
        grads = [p.grad for p in model.parameters() if p.grad is not None]
        return float(torch.sqrt(sum((g**2).sum() for g in grads)))

    for name, state in (("--init", init["model"]), ("checkpoint", None)):
        model = Scotti(cfg)
        if state is not None:
            load_initial_weights(model, state)
        else:
            model.load_state_dict(load_checkpoint(args.checkpoint)["model"])
        for c in picked:
            frames = [torch.from_numpy(data.frames(c).astype(np.float32))]
            t = data.targets(c)
            targets = ScottiTargets(
                torch.from_numpy(t.keypoints), torch.from_numpy(t.action),
                torch.from_numpy(t.progress),
            )  # fmt: skip
            model.train()
            if anchor.matched:
                model.cnn.norm.eval()  # --norm-statistics kept, as the fine-tune runs it
            model.zero_grad()
            before = rng_state(torch.device("cpu"))
            outputs, pooled = chunked_outputs_pooled(model, frames, cfg.window, STRIDE)
            task, _ = scotti_loss(outputs, targets, LossWeights(*LOSS_WEIGHTS))
            task.backward(retain_graph=True)  # type: ignore[no-untyped-call]
            task_norm = grad_norm(model)
            model.zero_grad()
            if anchor.matched:
                term = anchor.matched_term(model, frames, STRIDE, pooled, before)
            else:
                term = anchor.term(model, frames, STRIDE)
            (args.weight * term).backward()  # type: ignore[no-untyped-call]
            print(
                f"{name:10s} pull term {float(term.detach()):.4f}, gradient {grad_norm(model):.2f}"
                f" | task loss {float(task.detach()):.3f}, gradient {task_norm:.2f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
