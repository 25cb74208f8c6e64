"""``scotti train`` with per-task loss weights, for the single-task variants of Table 3.

    python experiments/train_variant.py --loss-weights POSE,ACTION,PROGRESS SCOTTI-TRAIN-ARGS...

Same model, same encoder, same data and schedule as ``scotti train``; only
the weights of the three losses differ (a weight of 0 switches a task off).
It wraps ``scotti.export.train_cli`` instead of changing it: the smallest
change there would be a ``--loss-weights`` flag feeding
``TrainOptions.loss_weights``, which this does from outside. Give the same
weights again with ``--resume``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from scotti.export import train_cli
from scotti.export.losses import LossWeights
from scotti.export.train import TrainOptions


def parse_weights(text: str) -> LossWeights:
    try:
        pose, action, progress = (float(x) for x in text.split(","))
    except ValueError:
        msg = f"--loss-weights wants three numbers POSE,ACTION,PROGRESS, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from None
    if min(pose, action, progress) < 0 or pose + action + progress == 0:
        msg = f"--loss-weights must be >= 0 and not all 0, got {text!r}"
        raise argparse.ArgumentTypeError(msg)
    return LossWeights(pose=pose, action=action, progress=progress)


def main(argv: list[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else argv
    front = argparse.ArgumentParser(add_help=False)
    front.add_argument("--loss-weights", type=parse_weights, required=True)
    known, rest = front.parse_known_args(words)
    weights: LossWeights = known.loss_weights

    options = train_cli._options  # the wrapped CLI's own option builder

    def with_weights(args: argparse.Namespace) -> TrainOptions:
        return replace(options(args), loss_weights=weights)

    train_cli._options = with_weights
    parser = argparse.ArgumentParser(prog="python experiments/train_variant.py")
    train_cli.add_arguments(parser)
    return train_cli.run(parser.parse_args(rest))


if __name__ == "__main__":
    raise SystemExit(main())
