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
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from scotti.export.evaluate import chunked_outputs_pooled
from scotti.export.model import Scotti


class Anchor:
    """A frozen copy of the initial weights and the weight of the pull towards them."""

    def __init__(self, initial: Scotti, weight: float) -> None:
        self.weight = weight
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


def relative_distance(pooled: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """sum |p - p0|^2 / sum |p0|^2 over a batch (B, E); the floor keeps an all-zero
    reference (an untrained model) from dividing by 0."""
    return ((pooled - reference) ** 2).sum() / (reference**2).sum().clamp_min(1e-12)
