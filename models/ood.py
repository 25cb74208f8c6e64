"""The ``unfamiliar`` score: how far a window's pooled vector lies from the training data.

The three heads read one pooled vector per window (export/model.py). Over
the training windows those vectors have a mean ``mu`` and a covariance,
shrunk towards a scaled identity (Ledoit and Wolf 2004) so that E dimensions
are estimated stably from a few thousand windows. The score of a window is
its Mahalanobis distance ``|| W (pooled - mu) ||`` with ``W`` the whitening
matrix of that covariance; a window scoring above ``threshold`` (a high
percentile of the scores of held-out subjects' windows) is ``unfamiliar``.

``OodStats`` travels in the graphs' metadata (``contract.META_OOD``) as JSON
with the arrays as base64 little-endian float32, and is fitted at export
(``scotti export --calibrate``, export/ood_calibration.py). A model without
it still runs: the score is None and ``info`` says it is not calibrated.

Also here: the one rule that turns flags into what is published
(``withheld``), shared by the daemon and ``scotti eval``.
"""

from __future__ import annotations

import base64
import functools
import json
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from scotti.models.errors import ModelContractError
from scotti.models.input_checks import OUT_OF_RANGE, UNLOADED

UNFAMILIAR: Final = "unfamiliar"
# The status line while it holds: fixed text (the score changes every frame, status must not).
UNFAMILIAR_REASON: Final = "unfamiliar: input unlike the training data (score above threshold)"
# Every flag that withholds the action, progress and repetition count, in order of precedence.
OOD_FLAGS: Final = (UNLOADED, OUT_OF_RANGE, UNFAMILIAR)


def window_reasons(input_reasons: tuple[str, ...], flags: tuple[str, ...]) -> tuple[str, ...]:
    """A window's reasons for its last prediction: its input checks', then the unfamiliar
    score's when that flag is among the prediction's ``flags``."""
    return (*input_reasons, UNFAMILIAR_REASON) if UNFAMILIAR in flags else input_reasons


F32 = npt.NDArray[np.float32]
_ROWS_PER_PRODUCT: Final = 8


def withheld(flags: Iterable[str]) -> str | None:
    """The flag that withholds this prediction's action (the first of ``OOD_FLAGS`` set)."""
    present = set(flags)
    return next((f for f in OOD_FLAGS if f in present), None)


def flag_shares(flag_sets: Iterable[Iterable[str]]) -> dict[str, Any]:
    """Share of predictions carrying each OOD flag, and of those withheld at all."""
    return shares_of(flag_counts(flag_sets))


def flag_counts(flag_sets: Iterable[Iterable[str]]) -> Counter[str]:
    """How many predictions carry each OOD flag (``any``: withheld at all) and how many
    there are (``predictions``). Counts of several sessions add up (``Counter.update``);
    shares would not."""
    counts: Counter[str] = Counter(dict.fromkeys((*OOD_FLAGS, "any", "predictions"), 0))
    for flags in flag_sets:
        present = set(flags)
        counts["predictions"] += 1
        counts.update(name for name in OOD_FLAGS if name in present)
        counts["any"] += withheld(present) is not None
    return counts


def shares_of(counts: Counter[str]) -> dict[str, Any]:
    """``flag_counts`` as shares of the predictions (None where there are none)."""
    n = counts["predictions"]
    shares: dict[str, Any] = {
        name: (counts[name] / n if n else None) for name in (*OOD_FLAGS, "any")
    }
    shares["predictions"] = n
    return shares


def format_flag_shares(shares: dict[str, Any] | None, info: dict[str, Any] | None) -> str:
    """One line for ``scotti eval``: the share of predictions each flag withheld."""
    if not shares or not shares.get("predictions"):
        return "  flagged: no predictions"
    parts = [f"{name} {100 * shares[name]:.2f} %" for name in OOD_FLAGS]
    line = f"  flagged (of {shares['predictions']} predictions): " + ", ".join(parts)
    if info is not None and not info.get("calibrated"):
        line += " (unfamiliar: model not calibrated)"
    return line


def _pack(a: npt.ArrayLike) -> str:
    return base64.b64encode(np.asarray(a, dtype="<f4").tobytes()).decode("ascii")


def _unpack(text: Any, shape: tuple[int, ...], what: str) -> F32:
    try:
        raw = base64.b64decode(str(text), validate=True)
        a = np.frombuffer(raw, dtype="<f4").astype(np.float32)
        return a.reshape(shape)
    except ValueError:
        msg = f"OOD statistics: {what} is not {shape} base64 float32"
        raise ModelContractError(msg) from None


@dataclass(frozen=True)
class OodStats:
    """Mean and whitening of the training windows' pooled vectors, and the threshold."""

    mean: F32  # (E,)
    whitening: F32  # (E, E): W with W C W^T = I for the shrunk covariance C
    threshold: float  # scores above it are unfamiliar
    summary: dict[str, Any] = field(default_factory=dict)  # what the card shows

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])

    def score(self, pooled: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Mahalanobis distance of each pooled vector (..., E) -> (...)."""
        pooled = np.asarray(pooled)
        z = np.subtract(pooled, self.mean, dtype=np.float64)
        rows = z.reshape(-1, z.shape[-1])
        w = np.empty_like(rows)
        w_t = self._whitening_t
        # A few rows per product: OpenBLAS gives a product of more than 2^18 multiply-adds
        # (16 rows at E=128) to its threads, which spin after each call (CPU time doubled
        # on 2 cores in the batched replay of ``scotti eval``); below that it stays on
        # this thread. 8 rows a product: a third of the CPU of one product per row.
        for start in range(0, len(rows), _ROWS_PER_PRODUCT):
            end = start + _ROWS_PER_PRODUCT
            np.matmul(rows[start:end], w_t, out=w[start:end])
        squares = np.einsum("ij,ij->i", w, w)  # one call, where w * w then a sum are two
        distance: npt.NDArray[np.float64] = np.sqrt(squares)
        return distance.reshape(z.shape[:-1])

    @functools.cached_property
    def _whitening_t(self) -> npt.NDArray[np.float64]:
        return np.ascontiguousarray(self.whitening.T, dtype=np.float64)

    def to_json(self) -> str:
        return json.dumps(
            {
                "dim": self.dim,
                "mean": _pack(self.mean),
                "whitening": _pack(self.whitening),
                "threshold": self.threshold,
                "summary": self.summary,
            },
            sort_keys=True,
        )

    @classmethod
    def from_json(cls, text: str, embed_dim: int) -> OodStats:
        """From the metadata value; any misfit is one ``ModelContractError`` line."""
        try:
            d = json.loads(text)
        except json.JSONDecodeError:
            d = None
        if not isinstance(d, dict) or not {"dim", "mean", "whitening", "threshold"} <= set(d):
            msg = "OOD statistics are not a JSON object with dim, mean, whitening, threshold"
            raise ModelContractError(msg)
        if d["dim"] != embed_dim:
            msg = f"OOD statistics are for E={d['dim']}, the model has E={embed_dim}"
            raise ModelContractError(msg)
        threshold = d["threshold"]
        if not isinstance(threshold, int | float) or not np.isfinite(threshold) or threshold <= 0:
            msg = f"OOD threshold must be a positive number, got {threshold!r}"
            raise ModelContractError(msg)
        raw_summary = d.get("summary")
        summary: dict[str, Any] = raw_summary if isinstance(raw_summary, dict) else {}
        return cls(
            mean=_unpack(d["mean"], (embed_dim,), "mean"),
            whitening=_unpack(d["whitening"], (embed_dim, embed_dim), "whitening"),
            threshold=float(threshold),
            summary=summary,
        )


def shrunk_covariance(x: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], float]:
    """Ledoit-Wolf covariance of rows ``x`` (N, E): (1 - s) S + s mu I, and the shrinkage s."""
    a = np.asarray(x, dtype=np.float64)
    n = a.shape[0]
    if n < 2:
        msg = f"need at least 2 vectors for a covariance, got {n}"
        raise ValueError(msg)
    z = a - a.mean(axis=0)
    s = z.T @ z / n  # (E, E) sample covariance
    mu = float(np.trace(s)) / s.shape[0]
    target = mu * np.eye(s.shape[0])
    d2 = float(((s - target) ** 2).sum())
    # Mean squared distance of each outer product z z^T from S, over n: the sampling
    # noise of S; sum_k ||z_k z_k^T - S||^2 = sum_k ||z_k||^4 - n ||S||^2.
    b2 = (float(((z * z).sum(axis=1) ** 2).sum()) - n * float((s * s).sum())) / n**2
    shrink = min(1.0, b2 / d2) if d2 > 0 else 1.0
    return (1.0 - shrink) * s + shrink * target, shrink


def fit(
    train_pooled: npt.ArrayLike, held_out_pooled: npt.ArrayLike, percentile: float = 99.0
) -> OodStats:
    """Mean and whitening from training windows; threshold at ``percentile`` of held-out scores."""
    train = np.asarray(train_pooled, dtype=np.float64)
    held = np.asarray(held_out_pooled, dtype=np.float64)
    if held.shape[0] < 1:
        msg = "need held-out windows to calibrate the threshold"
        raise ValueError(msg)
    mean = train.mean(axis=0)
    cov, shrink = shrunk_covariance(train)
    vals, vecs = np.linalg.eigh(cov)
    vals = np.maximum(vals, 1e-12 * float(vals.max()))
    whitening = (vecs / np.sqrt(vals)).T  # rows: eigenvectors scaled by 1/sqrt(eigenvalue)
    stats = OodStats(mean.astype(np.float32), whitening.astype(np.float32), 1.0)
    train_scores, held_scores = stats.score(train), stats.score(held)
    threshold = float(np.percentile(held_scores, percentile))
    pct = (50.0, 90.0, 99.0, 99.9)
    summary = {
        "method": "Mahalanobis distance of the pooled vector, Ledoit-Wolf shrunk covariance",
        "dim": int(mean.shape[0]),
        "shrinkage": shrink,
        "train_windows": int(train.shape[0]),
        "held_out_windows": int(held.shape[0]),
        "threshold_percentile": percentile,
        "threshold": threshold,
        "train_score_percentiles": {str(p): float(np.percentile(train_scores, p)) for p in pct},
        "held_out_score_percentiles": {str(p): float(np.percentile(held_scores, p)) for p in pct},
        "held_out_flagged": float((held_scores > threshold).mean()),
        "train_flagged": float((train_scores > threshold).mean()),
    }
    return OodStats(mean.astype(np.float32), whitening.astype(np.float32), threshold, summary)
