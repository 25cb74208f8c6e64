"""One coverage cell simulated and scored: its people's sessions rendered, each
replayed through the daemon's path (``scotti.evaluation.replay``, what ``scotti
eval`` runs), the frames pooled and scored the evaluation room's way, and every
prediction sorted by right or wrong, flagged or not, confident or not.

Wrong means an action label that is not the predicted one (transitions, which
have no action, are neither right nor wrong, as in the accuracy). Flagged means
withheld by the daemon: any of ``models.ood.OOD_FLAGS``. Confident means a
top probability above ``CONFIDENT``.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.evaluation.frames import FrameScores
from scotti.evaluation.replay import SessionReplay, replay_session
from scotti.evaluation.scores import task_metrics
from scotti.firmware_protocol.session import LabelRecord, SessionReader
from scotti.firmware_protocol.wrap import seq_delta
from scotti.models.contract import ACTIONS, NO_ACTION
from scotti.models.input_checks import OUT_OF_RANGE, UNLOADED
from scotti.models.ood import UNFAMILIAR, withheld
from scotti.models.runtime import ScottiRuntime
from scotti.sim.corpus import render_scene
from scotti.sim.scene import Scene, build_motion

CONFIDENT: Final = 0.9  # a wrong answer above this top probability is a confident one


@dataclass
class Counts:
    """Scored predictions of one cell by outcome; counts of several cells add up."""

    predictions: int = 0  # scored predictions whose time has an action label
    wrong: int = 0
    unloaded: int = 0
    out_of_range: int = 0
    unfamiliar: int = 0
    flagged: int = 0  # any flag: withheld by the daemon
    wrong_unfamiliar: int = 0
    wrong_flagged: int = 0
    wrong_unflagged: int = 0  # published, and wrong
    wrong_unflagged_confident: int = 0  # ... at a top probability above CONFIDENT

    def __add__(self, other: Counts) -> Counts:
        return Counts(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    def share(self, name: str) -> float | None:
        """``name`` as a share of the predictions (None when there are none)."""
        return getattr(self, name) / self.predictions if self.predictions else None

    @classmethod
    def of(cls, raw: dict[str, int]) -> Counts:
        return cls(**raw)


@dataclass(frozen=True)
class Detector:
    """A flag read as a detector of wrong predictions."""

    precision: float | None  # of the flagged predictions, the share that were wrong
    recall: float | None  # of the wrong predictions, the share that were flagged
    base_rate: float | None  # share of wrong predictions: a flag fired at random has it


def detector(counts: Counts, flag: str = "unfamiliar") -> Detector:
    """``flag`` is ``unfamiliar`` or ``flagged`` (any flag)."""
    fired = counts.unfamiliar if flag == "unfamiliar" else counts.flagged
    hits = counts.wrong_unfamiliar if flag == "unfamiliar" else counts.wrong_flagged
    return Detector(
        hits / fired if fired else None,
        hits / counts.wrong if counts.wrong else None,
        counts.share("wrong"),
    )


def prediction_counts(path: Path, replay: SessionReplay) -> tuple[Counts, Counter[str]]:
    """Every scored prediction of a replay, by outcome (labels read back from the file),
    and what the wrong answers that went out (wrong and unflagged) were read as: the
    action each named, counted.

    A prediction is matched to its label by unwrapped seq, as
    ``evaluation.frames.align`` does; the count of matches is checked against it.
    """
    labels = [r for r in _records(path) if isinstance(r, LabelRecord)]
    out = Counts()
    published_as: Counter[str] = Counter()
    if not replay.made or not labels:
        return out, published_as
    first = replay.made[0].ext - 1
    ext = first + seq_delta(labels[0].seq, first & 0xFFFF)
    prev = labels[0].seq
    index: dict[int, int] = {}
    for i, label in enumerate(labels):
        ext += seq_delta(label.seq, prev)
        prev = label.seq
        index[ext] = i
    matched = 0
    for m in replay.made:
        row = index.get(m.ext)
        if row is None:
            continue
        matched += 1
        true = labels[row].action
        if true == NO_ACTION:
            continue
        named = int(np.argmax(m.probs))
        wrong = named != true
        flags = set(m.flags)
        flagged = withheld(flags) is not None
        out.predictions += 1
        out.wrong += wrong
        out.unloaded += UNLOADED in flags
        out.out_of_range += OUT_OF_RANGE in flags
        out.unfamiliar += UNFAMILIAR in flags
        out.flagged += flagged
        out.wrong_unfamiliar += wrong and UNFAMILIAR in flags
        out.wrong_flagged += wrong and flagged
        out.wrong_unflagged += wrong and not flagged
        out.wrong_unflagged_confident += (
            wrong and not flagged and float(np.max(m.probs)) > CONFIDENT
        )
        if wrong and not flagged:
            published_as[ACTIONS[named]] += 1
    if matched != replay.evaluated:  # the same matching as the replay's, or a bug here
        msg = f"{path}: {matched} predictions matched, the replay scored {replay.evaluated}"
        raise RuntimeError(msg)
    return out, published_as


def _records(path: Path) -> list[Any]:
    with SessionReader(path) as reader:
        return list(reader)


def same_motion(scenes: Sequence[dict[str, Any]], baselines: Sequence[dict[str, Any]]) -> bool:
    """Whether every person's motion (poses, labels, floor) is the baseline's: a movement
    parameter an action does not read leaves it as it was (cheap: no physics)."""
    for raw, base in zip(scenes, baselines, strict=True):
        a = build_motion(Scene.model_validate(raw))
        b = build_motion(Scene.model_validate(base))
        if a.world.shape != b.world.shape:
            return False
        if not (
            np.array_equal(a.world, b.world)
            and np.array_equal(a.action, b.action)
            and _same(a.ground_z, b.ground_z)
        ):
            return False
    return True


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is b
    return bool(np.array_equal(a, b))


def score_scenes(
    scenes: Sequence[Scene], runtime: ScottiRuntime, workdir: Path, *, keep: bool = False
) -> dict[str, Any]:
    """Render each scene (one person each), replay, pool and score: a cell's result."""
    started = time.process_time()
    workdir.mkdir(parents=True, exist_ok=True)
    pooled: list[FrameScores] = []
    counts = Counts()
    published_as: Counter[str] = Counter()
    per_person = []
    for k, scene in enumerate(scenes):
        path = workdir / f"{scene.name}-{k}.ses"
        render_scene(scene, path, subject_id=scene.name)
        replay = replay_session(path, runtime)
        person, named = prediction_counts(path, replay)
        counts += person
        published_as += named
        pooled.append(replay.scores)
        per_person.append(task_metrics(replay.scores)["action_accuracy"])
        if not keep:
            path.unlink()
    metrics = task_metrics(FrameScores.concat(pooled))
    return {
        "metrics": {k: _finite(v) for k, v in metrics.items()},
        "counts": asdict(counts),
        # the wrong answers that went out, by the action they named (most first)
        "wrong_unflagged_as": dict(published_as.most_common()),
        "accuracy_per_person": [_finite(a) for a in per_person],
        "cpu_s": round(time.process_time() - started, 3),
    }


def _finite(value: float | int) -> float | int | None:
    """NaN (nothing to score) as None: the cache is JSON."""
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value
