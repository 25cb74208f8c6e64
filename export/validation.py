"""Three-way split: test subjects held out, validation drawn from the training subjects.

The test subjects (``--test-subjects``, else a seeded ``--test-fraction``)
are left out first and never looked at during training: not for best.pt,
not for early stopping. The validation set, which picks best.pt and says
when the run has reached its plateau, comes out of what is left: the
subjects named by ``--val-subjects``, else a seeded ``--val-fraction`` of
the training subjects (at least one whole subject, and at least one left
to train on); with a single training subject, the last ``val_fraction`` of
each of its sessions, as the test split does with a single subject.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from scotti.export.data import SessionArrays, TrainingDataError
from scotti.export.windows import split_by_subject

VAL_FRACTION = 0.15  # of the training subjects (or of each session, with one subject)


@dataclass(frozen=True)
class Splits:
    train: list[SessionArrays]
    validation: list[SessionArrays]
    test: list[SessionArrays]
    train_subjects: list[str]
    validation_subjects: list[str]
    test_subjects: list[str]
    test_kind: str  # "subject", "time" or "none", as Split.kind
    validation_kind: str  # the same, for the validation set

    def describe(self) -> dict[str, Any]:
        """What the checkpoint and the model card record (training_data["split"])."""
        return {
            "kind": self.test_kind,
            "validation_kind": self.validation_kind,
            "train_subjects": self.train_subjects,
            "validation_subjects": self.validation_subjects,
            "test_subjects": self.test_subjects,
            "train_files": sorted({s.path for s in self.train}),
            "validation_files": sorted({s.path for s in self.validation}),
            "test_files": sorted({s.path for s in self.test}),
        }


def three_way_split(
    sessions: Sequence[SessionArrays],
    *,
    test_subjects: Sequence[str] | None = None,
    test_fraction: float = 0.2,
    val_subjects: Sequence[str] | None = None,
    val_fraction: float = VAL_FRACTION,
    seed: int = 0,
) -> Splits:
    if not 0.0 <= val_fraction < 1.0:
        msg = f"--val-fraction must be in [0, 1), got {val_fraction}"
        raise TrainingDataError(msg)
    held = split_by_subject(sessions, test_subjects, test_fraction=test_fraction, seed=seed)
    clash = sorted(set(val_subjects or ()) & set(held.test_subjects))
    if clash and held.kind == "subject":
        msg = f"validation subject(s) {', '.join(clash)} are test subjects too"
        raise TrainingDataError(msg)
    try:
        # A different stream than the test draw's, so the two draws do not line up.
        val = split_by_subject(held.train, val_subjects, test_fraction=val_fraction, seed=seed + 1)
    except TrainingDataError as exc:
        msg = str(exc).replace("test subject", "validation subject")
        raise TrainingDataError(msg) from None
    return Splits(
        train=val.train,
        validation=val.test,
        test=held.test,
        train_subjects=val.train_subjects,
        validation_subjects=val.test_subjects,
        test_subjects=held.test_subjects,
        test_kind=held.kind,
        validation_kind=val.kind,
    )


def predates_validation_split(training_data: dict[str, Any]) -> bool:
    """Was this checkpoint written before runs had a validation split?"""
    split = training_data.get("split", {})
    return isinstance(split, dict) and "validation_subjects" not in split
