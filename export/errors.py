"""The root of every error raised by ``scotti.export`` (one-line messages)."""

from __future__ import annotations


class ExportError(Exception):
    """A checkpoint, export or proof that went wrong; printed as one line by the CLIs."""


class ParityError(ExportError):
    """An exported graph that disagrees with torch beyond the stated tolerance."""
