"""The ``unfamiliar`` score: how far a window's pooled vector lies from the training data.

The three heads read one pooled vector per window (export/model.py). Over
the training windows of each action those vectors have a mean ``m_a``; the
windows' spread around their own action's mean has one covariance, shrunk
towards a scaled identity (Ledoit and Wolf 2004) so that E dimensions are
estimated stably from a few thousand windows (the tied covariance of Lee et
al. 2018, "A simple unified framework for detecting out-of-distribution
samples"). With ``W`` the whitening matrix of that covariance, a window's
distance to action a is ``|| W (pooled - m_a) ||``. Each action has its own
threshold ``t_a``: a high percentile of the distances of held-out subjects'
windows the model called a. The score of a window is its distance to the
mean of the action the model calls it, in units of that action's threshold:
``|| W (pooled - m_a) || / t_a`` for the predicted a; above 1 it is
``unfamiliar``. Where no action is given, or the predicted one has no mean,
the score is the smallest ratio over the actions. Statistics fitted without
the held-out predictions measure every window against the nearest mean
(``by_prediction`` False, one threshold), Lee et al.'s rule; compared in
experiments/ood_scores.py.

Why per action and by the prediction: the actions' pooled vectors lie in
clusters apart. One mean and one covariance over all of them put a squat's
ordinary windows far from the middle: the global distance flagged 95 % of
sim/scenes/squat.toml's predictions (docs/ood.md). The distance to the
nearest mean flags no squat, but lets through windows of real walking that
the model calls a confident step_up (8 % of one Moticon file), which lie
nearer the walking mean than the step_up one; measured against the
predicted action's own threshold they are unfamiliar. Statistics without
action means (``class_means`` None: graphs calibrated before) keep the one
global distance and its threshold.

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
class ActionMeans:
    """Each action's mean of the training windows' pooled vectors, and its threshold."""

    actions: tuple[int, ...]  # (K,) the contract's action index of each row
    means: F32  # (K, E)
    thresholds: F32  # (K,) on the distance to that mean; a ratio above 1 is unfamiliar
    # True: a window is measured against the action the model calls it; False: against
    # the nearest mean, whatever the prediction (Lee et al.'s rule, one threshold for all)
    by_prediction: bool = True

    def __post_init__(self) -> None:
        k = len(self.actions)
        if k < 1 or self.means.shape[0] != k or self.thresholds.shape != (k,):
            msg = f"{k} actions need ({k}, E) means and ({k},) thresholds"
            raise ValueError(msg)

    @functools.cached_property
    def row_of_action(self) -> npt.NDArray[np.int64]:
        """Action index -> row (-1: that action has no mean), for any index the heads give."""
        rows = np.full(max(self.actions) + 1, -1, dtype=np.int64)
        rows[list(self.actions)] = np.arange(len(self.actions))
        return rows


@dataclass(frozen=True)
class OodStats:
    """Mean and whitening of the training windows' pooled vectors, and the threshold."""

    mean: F32  # (E,): of all training windows
    whitening: F32  # (E, E): W with W C W^T = I for the shrunk covariance C
    threshold: float  # scores above it are unfamiliar (1 with ``action_means``)
    summary: dict[str, Any] = field(default_factory=dict)  # what the card shows
    # None: the score is the distance to ``mean`` (one Gaussian over every window)
    action_means: ActionMeans | None = None

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])

    def score(
        self, pooled: npt.ArrayLike, actions: npt.ArrayLike | None = None
    ) -> npt.NDArray[np.float64]:
        """The score of each pooled vector (..., E) -> (...).

        With action means: the distance to the mean of ``actions`` (the predicted action
        of each vector, shape (...)) over that action's threshold; the smallest such
        ratio where ``actions`` is None or an action has no mean. Without: the distance
        to the training windows' mean.
        """
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
        if self.action_means is None:
            distance: npt.NDArray[np.float64] = np.sqrt(squares)
            return distance.reshape(z.shape[:-1])
        ratios = self._ratios(w, squares)
        chosen = ratios.min(axis=1)
        if actions is not None and self.action_means.by_prediction:
            rows_of = self.action_means.row_of_action
            a = np.asarray(actions, dtype=np.int64).reshape(-1)
            known = (a >= 0) & (a < len(rows_of))
            row = np.where(known, rows_of[np.where(known, a, 0)], -1)
            has = row >= 0
            chosen[has] = ratios[np.flatnonzero(has), row[has]]
        score: npt.NDArray[np.float64] = chosen.reshape(z.shape[:-1])
        return score

    def _ratios(
        self, w: npt.NDArray[np.float64], squares: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """(N, K) each whitened row's distance to each action's mean over its threshold."""
        centres, centre_squares, inverse_thresholds = self._whitened_centres
        # ||w - c_k||^2 = ||w||^2 - 2 w.c_k + ||c_k||^2 with c_k the whitened centres:
        # one (N, E) x (E, K) product instead of K differences.
        to_centres = squares[:, None] - 2.0 * (w @ centres.T) + centre_squares
        return np.sqrt(np.maximum(to_centres, 0.0)) * inverse_thresholds  # rounding dips < 0

    @functools.cached_property
    def _whitening_t(self) -> npt.NDArray[np.float64]:
        return np.ascontiguousarray(self.whitening.T, dtype=np.float64)

    @functools.cached_property
    def _whitened_centres(
        self,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """(K, E) action means in the whitened frame around ``mean``, their squared norms,
        and the actions' thresholds inverted."""
        assert self.action_means is not None
        am = self.action_means
        centres = np.subtract(am.means, self.mean, dtype=np.float64) @ self._whitening_t
        squares = np.einsum("ij,ij->i", centres, centres)
        return centres, squares, 1.0 / am.thresholds.astype(np.float64)

    def to_json(self) -> str:
        d: dict[str, Any] = {
            "dim": self.dim,
            "mean": _pack(self.mean),
            "whitening": _pack(self.whitening),
            "threshold": self.threshold,
            "summary": self.summary,
        }
        if self.action_means is not None:
            am = self.action_means
            d["actions"] = list(am.actions)
            d["action_means"] = _pack(am.means)
            d["action_thresholds"] = _pack(am.thresholds)
            d["by"] = "prediction" if am.by_prediction else "nearest"
        return json.dumps(d, sort_keys=True)

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
            action_means=_action_means_from(d, embed_dim),
        )


def _action_means_from(d: dict[str, Any], embed_dim: int) -> ActionMeans | None:
    """The per-action part of the metadata, if any; a misfit is one line."""
    if "action_means" not in d:
        return None
    actions = d.get("actions")
    if (
        not isinstance(actions, list)
        or not actions
        or not all(isinstance(a, int) and not isinstance(a, bool) and a >= 0 for a in actions)
        or len(set(actions)) != len(actions)
    ):
        msg = f"OOD statistics: actions must be distinct action indices, got {actions!r}"
        raise ModelContractError(msg)
    k = len(actions)
    means = _unpack(d["action_means"], (k, embed_dim), "action_means")
    thresholds = _unpack(d.get("action_thresholds"), (k,), "action_thresholds")
    if not (np.isfinite(thresholds).all() and (thresholds > 0).all()):
        msg = "OOD statistics: action_thresholds must be positive numbers"
        raise ModelContractError(msg)
    by = d.get("by", "prediction")
    if by not in ("prediction", "nearest"):
        msg = f"OOD statistics: by must be 'prediction' or 'nearest', got {by!r}"
        raise ModelContractError(msg)
    return ActionMeans(tuple(actions), means, thresholds, by_prediction=by == "prediction")


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


# An action with fewer training windows than this gets no mean of its own (a mean of
# a handful of windows is noise), and one with fewer held-out windows predicted as it
# no threshold of its own (the threshold of the nearest mean over every held-out window).
MIN_CLASS_WINDOWS: Final = 20


def fit(
    train_pooled: npt.ArrayLike,
    held_out_pooled: npt.ArrayLike,
    percentile: float = 99.0,
    train_labels: npt.ArrayLike | None = None,
    held_out_predicted: npt.ArrayLike | None = None,
    action_names: tuple[str, ...] = (),
) -> OodStats:
    """Statistics from training windows, thresholds at ``percentile`` of held-out scores.

    With ``train_labels`` (an action index per training window, negative for none):
    a mean per action and the covariance of the windows around their own action's
    mean (windows without an action, or of an action with fewer than
    ``MIN_CLASS_WINDOWS``, fit neither), and a threshold per action from the held-out
    windows ``held_out_predicted`` calls it (the model's action per held-out window).
    Without predictions the score is the distance to the nearest mean, whatever the
    model says, with one threshold (Lee et al. 2018). Without labels, or where no
    action has that many windows (a small calibration set), one global mean.
    ``action_names`` (indexed by action) only names the actions in the summary.
    """
    train = np.asarray(train_pooled, dtype=np.float64)
    held = np.asarray(held_out_pooled, dtype=np.float64)
    if held.shape[0] < 1:
        msg = "need held-out windows to calibrate the threshold"
        raise ValueError(msg)
    labels = None if train_labels is None else np.asarray(train_labels)
    if labels is not None and labels.shape != (train.shape[0],):
        msg = f"need one label per training window, got {labels.shape} for {train.shape[0]}"
        raise ValueError(msg)
    predicted = None if held_out_predicted is None else np.asarray(held_out_predicted)
    if predicted is not None and predicted.shape != (held.shape[0],):
        msg = f"need one prediction per held-out window, got {predicted.shape}"
        raise ValueError(msg)
    kept: list[int] = []
    if labels is not None:
        present = [int(a) for a in np.unique(labels[labels >= 0])]
        kept = [a for a in present if int((labels == a).sum()) >= MIN_CLASS_WINDOWS]
    mean = train.mean(axis=0)
    if not kept:  # no labels, or too few windows of every action: one Gaussian
        cov, shrink = shrunk_covariance(train)
        whitening = _whitening(cov)
        stats = OodStats(mean.astype(np.float32), whitening, 1.0)
        threshold = float(np.percentile(stats.score(held), percentile))
        stats = OodStats(stats.mean, whitening, threshold)
        method = "Mahalanobis distance of the pooled vector, Ledoit-Wolf shrunk covariance"
        per_action: dict[str, Any] = {}
    else:
        assert labels is not None
        means = np.stack([train[labels == a].mean(axis=0) for a in kept])
        residuals = np.concatenate(
            [train[labels == a] - m for a, m in zip(kept, means, strict=True)]
        )
        cov, shrink = shrunk_covariance(residuals)
        whitening = _whitening(cov)
        unit = ActionMeans(tuple(kept), means.astype(np.float32), np.ones(len(kept), np.float32))
        distances = OodStats(mean.astype(np.float32), whitening, 1.0, {}, unit)
        held_d = _distances(distances, held)  # (n, K) plain distances (thresholds 1)
        nearest = float(np.percentile(held_d.min(axis=1), percentile))
        thresholds = np.full(len(kept), nearest)
        per_action = {}
        for row, a in enumerate(kept):
            own = held_d[predicted == a, row] if predicted is not None else np.zeros(0)
            if len(own) >= MIN_CLASS_WINDOWS:
                thresholds[row] = float(np.percentile(own, percentile))
            name = action_names[a] if 0 <= a < len(action_names) else str(a)
            per_action[name] = {
                "train_windows": int((labels == a).sum()),
                "held_out_windows": len(own),
                "threshold": float(thresholds[row]),
            }
        by_prediction = predicted is not None
        am = ActionMeans(
            tuple(kept), means.astype(np.float32), thresholds.astype(np.float32), by_prediction
        )
        stats = OodStats(mean.astype(np.float32), whitening, 1.0, {}, am)
        threshold = 1.0
        method = (
            "Mahalanobis distance of the pooled vector to the mean of the predicted action "
            "over that action's threshold, Ledoit-Wolf shrunk within-action covariance"
            if by_prediction
            else "Mahalanobis distance of the pooled vector to the nearest action's mean, "
            "Ledoit-Wolf shrunk within-action covariance"
        )
    train_scores = stats.score(train, labels if kept else None)
    held_scores = stats.score(held, predicted)
    pct = (50.0, 90.0, 99.0, 99.9)
    summary: dict[str, Any] = {
        "method": method,
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
    if per_action:
        summary["actions"] = per_action
    return OodStats(stats.mean, stats.whitening, threshold, summary, stats.action_means)


def _whitening(cov: npt.NDArray[np.float64]) -> F32:
    vals, vecs = np.linalg.eigh(cov)
    vals = np.maximum(vals, 1e-12 * float(vals.max()))
    whitening: F32 = (vecs / np.sqrt(vals)).T.astype(np.float32)  # rows: vectors / sqrt(value)
    return whitening


def _distances(stats: OodStats, x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(N, K) distances of rows ``x`` to each action's mean (thresholds of ``stats``: 1)."""
    z = np.subtract(x, stats.mean, dtype=np.float64)
    w = z @ stats.whitening.T.astype(np.float64)
    return stats._ratios(w, np.einsum("ij,ij->i", w, w))
