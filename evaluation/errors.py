"""The evaluation room's error root."""

from __future__ import annotations

from scotti.daemon.errors import DaemonError


class EvaluationError(DaemonError):
    """A mistake in what was asked to evaluate: one line for the user."""
