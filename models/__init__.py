"""SCOTTI model room: the contract, progress labels, metrics and the onnxruntime wrapper.

The runtime names load lazily, so that importing ``scotti.models`` (or its
contract) from the simulator does not pull onnxruntime in.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from scotti.models.errors import ModelContractError, ModelError, ModelInputError
from scotti.models.metrics import (
    PrecisionMargin,
    action_accuracy,
    app,
    confusion_matrix,
    joint_angles_deg,
    mpjae_deg,
    mpjpe_mm,
    precision_margin,
    progress_mse,
)
from scotti.models.progress import (
    PeakParams,
    ProgressLabels,
    label_progress,
    progress_from_indicator,
    progress_indicator,
)

if TYPE_CHECKING:
    from scotti.models.runtime import ScottiRuntime, StepResult, WindowResult, load_pair
    from scotti.models.streaming import EmbeddingCache, StreamingWindow

_LAZY = {
    "ScottiRuntime": "scotti.models.runtime",
    "StepResult": "scotti.models.runtime",
    "WindowResult": "scotti.models.runtime",
    "load_pair": "scotti.models.runtime",
    "EmbeddingCache": "scotti.models.streaming",
    "StreamingWindow": "scotti.models.streaming",
}

__all__ = [
    "EmbeddingCache",
    "ModelContractError",
    "ModelError",
    "ModelInputError",
    "PeakParams",
    "PrecisionMargin",
    "ProgressLabels",
    "ScottiRuntime",
    "StepResult",
    "StreamingWindow",
    "WindowResult",
    "action_accuracy",
    "app",
    "confusion_matrix",
    "joint_angles_deg",
    "label_progress",
    "load_pair",
    "mpjae_deg",
    "mpjpe_mm",
    "precision_margin",
    "progress_from_indicator",
    "progress_indicator",
    "progress_mse",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    msg = f"module 'scotti.models' has no attribute {name!r}"
    raise AttributeError(msg)
