"""What docs/coverage.md is written from, and how it writes a figure: a cell's
checkpoint read as a Row, the Summary of the run, the goals a cell and a scene file
are held to, and the small formatters every section shares (experiments/coverage_doc.py
puts the sections together)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

from coverage_grid import Parameter
from coverage_score import Counts

GOAL_CELL_ACCURACY: Final = 0.90
GOAL_CELL_APP: Final = 0.85
GOAL_SCENE_ACCURACY: Final = 0.95
GOAL_SCENE_APP: Final = 0.88
GOAL_WRONG_UNFLAGGED: Final = 0.05


@dataclass(frozen=True)
class Row:
    """A cell's checkpoint, read for the doc."""

    result: dict[str, Any]

    @property
    def action(self) -> str:
        return str(self.result["action"])

    @property
    def path(self) -> str | None:
        path = self.result["path"]
        return None if path is None else str(path)

    @property
    def label(self) -> str:
        return str(self.result["label"]).split(": ", 1)[-1]

    @property
    def unchanged(self) -> bool:
        return bool(self.result.get("unchanged"))

    @property
    def error(self) -> str | None:
        error = self.result.get("error")
        return None if error is None else str(error)

    @property
    def counts(self) -> Counts:
        return Counts.of(self.result["counts"]) if "counts" in self.result else Counts()

    @property
    def wrong_unflagged_as(self) -> dict[str, int]:
        """The wrong answers that went out, by the action they named (a checkpoint
        written before this was counted has none)."""
        return {str(k): int(v) for k, v in self.result.get("wrong_unflagged_as", {}).items()}

    def read_as(self, most: int = 2) -> str:
        """The ``most`` actions the wrong published answers named, as shares of all
        the cell's predictions: ``walking 88.5 %, standing 0.9 %``."""
        total = self.counts.predictions
        named = sorted(self.wrong_unflagged_as.items(), key=lambda kv: (-kv[1], kv[0]))
        if not total or not named:
            return "-"
        return ", ".join(f"{action} {pct(n / total)}" for action, n in named[:most])

    def metric(self, name: str) -> float | None:
        value = self.result.get("metrics", {}).get(name)
        return None if value is None else float(value)

    @property
    def accuracy(self) -> float | None:
        return self.metric("action_accuracy") if self.counts.predictions else None

    @property
    def app(self) -> float | None:
        return self.metric("app")


@dataclass(frozen=True)
class Summary:
    """Everything the doc shows besides the rows."""

    command: str
    people: int
    seconds: float
    model: str
    model_sha: str
    commit: str
    date: str
    actions: tuple[str, ...]
    parameters: tuple[Parameter, ...]
    cpu_minutes: float
    wall_minutes: float
    jobs_left: int
    jobs_run: int = 0  # cells and scene files scored by this invocation (the rest: cache)


def scene_accuracy(scene: dict[str, Any]) -> float | None:
    value = scene["metrics"].get("action_accuracy")
    return None if value is None or not scene["counts"]["predictions"] else float(value)


def show(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def sort_key(value: float | None, missing: float = -1.0) -> float:
    """A figure for sorting: a missing one sorts first (the worst) unless told otherwise."""
    return missing if value is None or not math.isfinite(value) else value


def ratio(a: int, b: int) -> float | None:
    return a / b if b else None


def pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def num(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def verdict(ok: bool) -> str:
    return "pass" if ok else "**fail**"
