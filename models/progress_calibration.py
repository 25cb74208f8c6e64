"""Progress calibration: the progress head's output mapped onto what it means, per action.

Trained with a squared error, the progress head hedges where a repetition's
phase is uncertain (the arrival at the top of a squat, the moment a step
lands): it pulls its output towards the middle, and its 0.75 means 0.87 on
average. A monotone map per predicted action, fitted on held-out subjects'
frames (isotonic regression of the label on the output, in bins), undoes
that: measured on the shipped model, fitted on the 4 validation subjects and
scored on 2 test subjects, progress MSE 0.0245 -> 0.0213 and APP 0.906 ->
0.915, squat p95 0.76 -> 0.87 (docs/evaluation.md has the whole test set).
It is monotone, so the order of a repetition's frames, and hence the
repetition counter's rising and falling, is kept.

``ProgressCalibration`` travels in the graphs' metadata
(``contract.META_PROGRESS_CALIBRATION``) as JSON and is applied by the runtime
of either form (``ProgressMapping``) to every prediction, daemon and ``scotti
eval`` alike; it is fitted by ``scotti calibrate`` (evaluation/calibrate_cli.py). A model
without it gives the network's own progress. Numpy only.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from scotti.models.contract import (
    ACTIONS,
    META_PROGRESS_CALIBRATION,
    NUM_ACTIONS,
    has_progress,
)
from scotti.models.errors import ModelContractError

BINS: Final = 50  # quantile bins of the output per action: a smooth map from ~10^4 frames
MIN_SPAN: Final = 0.5  # a fitted map narrower than this is not stretched to 0..1
MIN_FRAMES: Final = 500  # an action with fewer held-out frames keeps its output as it is


@dataclass(frozen=True)
class ProgressCalibration:
    """A monotone piecewise-linear map per action index: output -> calibrated progress."""

    knots: dict[int, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]
    summary: dict[str, Any] = field(default_factory=dict)

    def apply(self, progress: npt.ArrayLike, actions: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """(B,) progress through the map of each row's action (index into ACTIONS)."""
        p = np.asarray(progress, dtype=np.float32)
        a = np.asarray(actions)
        out = p.copy()
        for action, (x, y) in self.knots.items():
            rows = a == action
            if rows.any():
                out[rows] = np.interp(p[rows], x, y)
        return out

    def to_json(self) -> str:
        maps = {ACTIONS[a]: {"x": x.tolist(), "y": y.tolist()} for a, (x, y) in self.knots.items()}
        return json.dumps({"maps": maps, "summary": self.summary}, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ProgressCalibration:
        """The metadata's JSON; a malformed one is a ModelContractError (one line)."""
        try:
            data = json.loads(text)
            knots = {}
            for name, m in data["maps"].items():
                x = np.asarray(m["x"], dtype=np.float64)
                y = np.asarray(m["y"], dtype=np.float64)
                if x.ndim != 1 or x.shape != y.shape or x.size < 1:
                    raise ValueError(name)
                if np.any(np.diff(x) < 0) or np.any(np.diff(y) < 0):
                    raise ValueError(f"{name} not monotone")
                if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
                    raise ValueError(f"{name} not finite")
                knots[ACTIONS.index(name)] = (x, y)
            summary = data.get("summary", {})
        except (ValueError, KeyError, TypeError) as exc:
            msg = f"model metadata holds a malformed progress calibration ({exc})"
            raise ModelContractError(msg) from None
        return cls(knots, summary if isinstance(summary, dict) else {})


@dataclass(frozen=True)
class ProgressMapping:
    """What a runtime of either form (models/runtime.py, models/kv_streaming.py) does with
    the map its graph carries: applies it to every prediction, or, switched off, gives
    the head's output as it is (what ``scotti calibrate`` fits a map on)."""

    carried: ProgressCalibration | None = None
    switched_on: bool = True

    @classmethod
    def from_metadata(cls, meta: Mapping[str, str], *, switched_on: bool = True) -> ProgressMapping:
        """The map in a graph's metadata (ModelContractError if malformed), if any."""
        text = meta.get(META_PROGRESS_CALIBRATION)
        carried = ProgressCalibration.from_json(text) if text is not None else None
        return cls(carried, switched_on)

    @property
    def applied(self) -> ProgressCalibration | None:
        """The map applied to every progress output (None: the head's output as it is)."""
        return self.carried if self.switched_on else None

    def __call__(
        self, progress: npt.NDArray[np.float32], logits: npt.NDArray[np.float32]
    ) -> npt.NDArray[np.float32]:
        """(B,) progress through the map of each row's predicted action."""
        cal = self.applied
        return progress if cal is None else cal.apply(progress, np.argmax(logits, axis=-1))

    def info(self) -> dict[str, Any]:
        """What ``info`` says about progress: calibrated (and on what) or why not."""
        cal = self.applied
        if cal is None:
            why = "switched off" if self.carried is not None else "the model carries none"
            return {"calibrated": False, "reason": why}
        return {"calibrated": True, "summary": cal.summary}


def fit(
    output: npt.ArrayLike,
    label: npt.ArrayLike,
    action: npt.ArrayLike,
    bins: int = BINS,
    min_frames: int = MIN_FRAMES,
) -> ProgressCalibration:
    """Per predicted action with a progress: the isotonic map from ``output`` to ``label``.

    Frames without a label (NaN) are left out. Within an action the outputs are cut
    into ``bins`` quantile bins; the bins' mean labels are made non-decreasing by
    pooling adjacent violators, and each bin's (mean output, pooled label) is a knot.
    """
    p = np.asarray(output, dtype=np.float64)
    t = np.asarray(label, dtype=np.float64)
    a = np.asarray(action)
    knots: dict[int, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]] = {}
    frames: dict[str, int] = {}
    for index in range(NUM_ACTIONS):
        rows = (a == index) & np.isfinite(t) & np.isfinite(p)
        if not has_progress(index) or rows.sum() < min_frames:
            continue
        knots[index] = _reach_both_ends(*_isotonic_knots(p[rows], t[rows], bins))
        frames[ACTIONS[index]] = int(rows.sum())
    calibration = ProgressCalibration(
        knots,
        {
            "method": f"isotonic per predicted action, {bins} quantile bins of the output",
            "frames": frames,
        },
    )
    # How much it buys on the frames it was fitted on (callers add which frames those were).
    calibration.summary["mse_before"] = _mse(p, t)
    calibration.summary["mse_after"] = _mse(calibration.apply(p, a), t)
    return calibration


def _mse(output: npt.ArrayLike, label: npt.NDArray[np.float64]) -> float:
    rows = np.isfinite(label)
    return float(np.mean((np.asarray(output, np.float64)[rows] - label[rows]) ** 2))


def _reach_both_ends(
    kx: npt.NDArray[np.float64], ky: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The map reaches 0 and 1 where the head does: knots (0, 0) and (1, 1) past the data.

    A bin's pooled label is a mean, and the outputs' extreme bins hold frames of
    many phases (the top 2 % of a squat model's outputs are frames labelled 0.6
    to 1), so the plain isotonic map never went past 0.74 to 0.88: a repetition
    never completed. The map therefore runs on from its last knot to (1, 1) and
    from (0, 0) to its first, so an output the head gives with full certainty
    maps to the end itself. Pinning the end knots instead (the extreme bins' mean
    outputs mapped to 0 and 1) moved the frames those bins hold away from their
    labels: on the model shipped with it, held-out progress MSE 0.0216 against
    0.0192 for the head alone, APP 0.9147 against 0.9187; on the very frames it
    was fitted on it raised the MSE, 0.0199 -> 0.0213 (docs/evaluation.md). The
    map stays monotone. A map that spans less than ``MIN_SPAN`` is a model
    without evidence of progress for that action, left as it is.
    """
    if kx.size < 3 or float(ky[-1] - ky[0]) < MIN_SPAN:
        return kx, ky
    if kx[0] > 0.0:
        kx, ky = np.r_[0.0, kx], np.r_[0.0, ky]
    if kx[-1] < 1.0:
        kx, ky = np.r_[kx, 1.0], np.r_[ky, 1.0]
    return kx, ky


def _isotonic_knots(
    x: npt.NDArray[np.float64], y: npt.NDArray[np.float64], bins: int
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    order = np.argsort(x, kind="stable")
    x, y = x[order], y[order]
    groups = np.array_split(np.arange(x.size), min(bins, x.size))
    # Blocks of (output sum, label sum, count), merged while a block's mean label
    # exceeds the next one's (pool adjacent violators).
    blocks: list[list[float]] = []
    for g in groups:
        blocks.append([float(x[g].sum()), float(y[g].sum()), float(g.size)])
        while len(blocks) > 1 and blocks[-2][1] / blocks[-2][2] > blocks[-1][1] / blocks[-1][2]:
            last = blocks.pop()
            for k in range(3):
                blocks[-1][k] += last[k]
    kx = np.array([b[0] / b[2] for b in blocks])
    ky = np.clip(np.array([b[1] / b[2] for b in blocks]), 0.0, 1.0)
    return kx, ky
