"""A uniform weight soup: the mean of the weights of fine-tunes from one start.

    python experiments/weight_soup.py runs/A/best.pt runs/B/best.pt [...] -o runs/SOUP/best.pt

Fine-tunes of one graph on one corpus that differ only in their seed end close
to each other, and the mean of their weights is a model of the same shape
(Wortsman et al., 2022, "Model soups"): its figures carry less of a single
seed's draw. The candidates of docs/generalisation.md ("Where a step starts")
failed the rule by less than two seeds of one recipe differ from each other;
a soup of those seeds is judged by the same rule.

Every checkpoint must have the same config, the same weight names and shapes;
``model`` (the weights export reads: the moving average) and ``trained_model``
are averaged tensor by tensor (integer buffers, such as a norm's batch count,
must agree and are kept). The output holds what ``scotti export`` reads
(config, weights, training data, options) plus ``soup``, the sources; its
``metrics`` and ``history`` are the first source's (``soup`` says whose). Read
and written by export/checkpoint.py, as training does. ``scotti
export`` then makes the graph as for any checkpoint (``EXPORT_ONLY=1
scripts/train_wide.sh`` with ``RUN`` the output's folder).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

AVERAGED = ("model", "trained_model")
KEPT = ("config", "epoch", "options", "training_data", "metrics", "history")


class SoupError(ValueError):
    """Checkpoints that cannot be averaged: one line that says why."""


def soup(checkpoints: list[dict[str, Any]], names: list[str]) -> dict[str, Any]:
    """The uniform soup of ``checkpoints`` (torch state, as ``torch.load`` gives it)."""
    import torch

    if len(checkpoints) < 2:
        msg = "a soup needs at least two checkpoints"
        raise SoupError(msg)
    first = checkpoints[0]
    for name, ck in zip(names[1:], checkpoints[1:], strict=True):
        if ck.get("config") != first.get("config"):
            msg = f"{name}: its config differs from {names[0]}'s: not the same model"
            raise SoupError(msg)
    out: dict[str, Any] = {k: first[k] for k in KEPT if k in first}
    for key in AVERAGED:
        if not all(key in ck for ck in checkpoints):
            if key == "model":
                msg = "every checkpoint needs its 'model' weights"
                raise SoupError(msg)
            continue
        states = [ck[key] for ck in checkpoints]
        names_0 = list(states[0])
        mean: dict[str, Any] = {}
        for name, state in zip(names, states, strict=True):
            if list(state) != names_0:
                msg = f"{name}: its {key!r} weights are not named as {names[0]}'s"
                raise SoupError(msg)
        for weight in names_0:
            tensors = [s[weight] for s in states]
            if any(t.shape != tensors[0].shape for t in tensors):
                msg = f"{weight}: shapes {[tuple(t.shape) for t in tensors]} differ"
                raise SoupError(msg)
            if tensors[0].is_floating_point():
                mean[weight] = (
                    torch.stack([t.double() for t in tensors]).mean(0).to(tensors[0].dtype)
                )
            elif all(torch.equal(t, tensors[0]) for t in tensors):
                mean[weight] = tensors[0].clone()
            else:
                msg = f"{weight}: an integer buffer that differs between the checkpoints"
                raise SoupError(msg)
        out[key] = mean
    out["soup"] = list(names)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoints", nargs="+", type=Path)
    parser.add_argument("-o", "--output", type=Path, required=True)
    args = parser.parse_args(argv)
    from scotti.export.checkpoint import CheckpointError, load_checkpoint, save_checkpoint

    try:
        loaded = [load_checkpoint(path) for path in args.checkpoints]
        out = soup(loaded, [str(p) for p in args.checkpoints])
    except (CheckpointError, SoupError) as exc:
        print(f"weight_soup: {exc}", file=sys.stderr)
        return 2
    save_checkpoint(out, args.output)
    print(f"weight_soup: {args.output}: the mean of {len(loaded)} checkpoints' weights")
    return 0


if __name__ == "__main__":
    sys.exit(main())
