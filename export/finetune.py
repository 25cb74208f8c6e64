"""Fine-tuning: start from another run's weights (``--init``), freeze parts (``--freeze``)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from scotti.export.errors import ExportError
from scotti.export.model import Scotti

# Parts of the model that fine-tuning may keep fixed: the per-frame CNN, the
# encoder (class token, positions or the streaming form's relative biases,
# transformer layers, final norm, pooling) and
# each task's head. Freezing all but one head fine-tunes that task alone and
# leaves the other outputs exactly as they were (a zero loss weight does not:
# the optimiser's weight decay still moves a head that is not frozen).
FREEZE_GROUPS = ("cnn", "encoder", "pose_head", "action_head", "progress_head")
HEADS = ("pose_head", "action_head", "progress_head")


def freeze_parts(model: Scotti, groups: Sequence[str]) -> list[torch.nn.Module]:
    """Stop gradients into the named parts; returns their modules (kept in eval mode
    while training, so batch-norm statistics and dropout stay as they were)."""
    unknown = sorted(set(groups) - set(FREEZE_GROUPS))
    if unknown:
        msg = f"cannot freeze {', '.join(unknown)}: the parts are {', '.join(FREEZE_GROUPS)}"
        raise ExportError(msg)
    modules: list[torch.nn.Module] = []
    params: list[torch.nn.Parameter] = []
    if "cnn" in groups:
        modules.append(model.cnn)
        params += list(model.cnn.parameters())
    if "encoder" in groups:
        params += [model.class_token, model.pool_weights]
        if model.streaming is not None:  # layers and final norm live in one module
            modules.append(model.streaming)
            params += list(model.streaming.parameters())
        else:
            modules += [model.encoder, model.ln_final]
            params += [model.positions]
            params += list(model.encoder.parameters()) + list(model.ln_final.parameters())
    for head in HEADS:
        if head in groups:
            module = getattr(model, head)
            modules.append(module)
            params += list(module.parameters())
    if set(FREEZE_GROUPS) <= set(groups):
        msg = "--freeze names every part: nothing would be trained"
        raise ExportError(msg)
    for p in params:
        p.requires_grad_(False)
    return modules


def kept_norm(model: Scotti) -> torch.nn.Module:
    """``--norm-statistics kept``: the frame CNN's batch norm, to be kept in eval mode
    while training (its scale and shift still train). An exported graph folded the norm
    into the projection and left the identity: batch statistics would standardise
    again what the graph already had, and the first step would train another function
    than the graph's (experiments/norm_statistics.py: farther than a whole fine-tune
    moved the shipped model's pooled vectors)."""
    return model.cnn.norm


def load_initial_weights(model: Scotti, state: dict[str, torch.Tensor]) -> list[str]:
    """Start from another run's weights (``--init``); returns what could not be copied whole.

    The action head may have grown since the checkpoint (the contract appends
    actions at the end): its rows for the actions both know are copied, the new
    ones keep their fresh initialisation. Any other difference is an error.
    """
    own = model.state_dict()
    notes: list[str] = []
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    if missing or unexpected:
        msg = f"--init checkpoint does not fit this model (missing {missing[:3]}, extra "
        msg += f"{unexpected[:3]})"
        raise ExportError(msg)
    merged: dict[str, torch.Tensor] = {}
    for name, value in state.items():
        mine = own[name]
        if value.shape == mine.shape:
            merged[name] = value
        elif (
            name.startswith("action_head.")
            and value.shape[1:] == mine.shape[1:]
            and value.shape[0] < mine.shape[0]
        ):
            grown = mine.clone()
            grown[: value.shape[0]] = value
            merged[name] = grown
            notes.append(f"{name}: {value.shape[0]} of {mine.shape[0]} rows from the checkpoint")
        else:
            msg = f"--init checkpoint's {name} is {tuple(value.shape)}, this model's "
            msg += f"{tuple(mine.shape)}"
            raise ExportError(msg)
    model.load_state_dict(merged)
    return notes
