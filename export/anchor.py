"""Fine-tuning that keeps the model's representation near where it started (``--keep-near``).

Why: every fine-tune of the shipped model on new data (slow walkers, foreign
insoles, other tempi) so far read more real walking right, but moved the
pooled vectors of real walks recorded by other insoles away from the walking
mean the unfamiliar flag is calibrated on, so the flag withheld more of them
(docs/generalisation.md, "Slow walkers"). The flag is fitted on the pooled
vector the heads read, so that is the vector this term holds: each training
window's pooled vector is pulled towards what the initial weights (``--init``)
give for the same input.

The term is a relative squared distance, sum |p - p0|^2 / sum |p0|^2 over the
windows, so its weight does not depend on the embedding's scale. Both sides
run in eval mode: with the model's dropout on, the shipped model is farther
from itself at the first step than a whole fine-tune (runs/v29) moved its
pooled vectors, and the gradient would be mostly dropout's noise. So the
trained model runs a second, dropout-free pass over the first chunk of each
batch (about a quarter of its windows) for this term, and the reference runs
without gradients. Weigh it by its gradient, not its value:
experiments/anchor_gradients.py prints both against the task's.

That eval-mode pass (``--keep-near-pass eval``) reads the trained model's moving
batch-norm statistics, which a fine-tune moves, so part of its pull chases them
(runs/v31: the pull's gradient 2-10 times the task's). ``--keep-near-pass
matched`` compares the training pass itself instead: the reference replays it
in training mode with the same dropout masks (the random generator rewound to
where the training pass began) and so with its own batch statistics of the
same batch. The term is then exactly 0 until the weights move, costs one
gradient-free pass of the reference over the whole batch and no second pass of
the trained model, and has no running statistics to chase.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from scotti.export.evaluate import chunked_outputs_pooled
from scotti.export.model import Scotti
from scotti.export.rng_state import RngState, rng_state, set_rng_state

PASSES = ("eval", "matched")  # --keep-near-pass


class Anchor:
    """A frozen copy of the initial weights and the weight of the pull towards them."""

    def __init__(self, initial: Scotti, weight: float, pass_: str = "eval") -> None:
        if pass_ not in PASSES:
            msg = f"unknown --keep-near-pass {pass_!r} (one of {', '.join(PASSES)})"
            raise ValueError(msg)
        self.weight = weight
        self.matched = pass_ == "matched"
        self.model = copy.deepcopy(initial).eval()
        for p in self.model.parameters():
            p.requires_grad_(False)

    def to(self, device: torch.device) -> Anchor:
        self.model.to(device)
        return self

    def term(
        self, model: Scotti, chunk_frames: Sequence[torch.Tensor], stride: int
    ) -> torch.Tensor:
        """The relative squared distance of ``model``'s pooled vectors to the reference's
        over the first chunk's windows, both without dropout (with gradients into ``model``)."""
        first = list(chunk_frames[:1])
        window = self.model.cfg.window
        with torch.no_grad():
            _, reference = chunked_outputs_pooled(self.model, first, window, stride)
        was_training = model.training
        model.eval()
        try:
            _, pooled = chunked_outputs_pooled(model, first, window, stride)
        finally:
            model.train(was_training)
        return relative_distance(pooled.float(), reference.float())

    def matched_term(
        self,
        model: Scotti,
        chunk_frames: Sequence[torch.Tensor],
        stride: int,
        pooled: torch.Tensor,
        rng_before: RngState,
    ) -> torch.Tensor:
        """The relative squared distance of ``pooled`` (the training pass's vectors of every
        window of the batch) to the reference's replay of that pass: each module in the
        trained model's mode, the random generator at ``rng_before`` (so the same dropout
        masks), batch statistics of the same batch. The generator and the reference's
        running statistics are put back afterwards, so training draws what it would have."""
        after = rng_state(pooled.device)
        buffers = {k: b.clone() for k, b in self.model.named_buffers()}
        for mine, theirs in zip(self.model.modules(), model.modules(), strict=True):
            mine.training = theirs.training
        try:
            set_rng_state(rng_before, pooled.device)
            with torch.no_grad():
                _, reference = chunked_outputs_pooled(
                    self.model, chunk_frames, self.model.cfg.window, stride
                )
        finally:
            set_rng_state(after, pooled.device)
            self.model.load_state_dict(buffers, strict=False)
            self.model.eval()
        return relative_distance(pooled.float(), reference.float())


def relative_distance(pooled: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """sum |p - p0|^2 / sum |p0|^2 over a batch (B, E); the floor keeps an all-zero
    reference (an untrained model) from dividing by 0."""
    return ((pooled - reference) ** 2).sum() / (reference**2).sum().clamp_min(1e-12)
