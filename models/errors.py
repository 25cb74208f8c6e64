"""Errors of the ``models`` room: one root, one-line messages.

``ModelError`` is what the daemon catches at start to print one line and
exit non-zero; foreign errors (onnxruntime, onnx, OS) are translated into it
at the boundary.
"""

from __future__ import annotations


class ModelError(Exception):
    """Root of every error raised by ``scotti.models``."""


class ModelContractError(ModelError):
    """A model file that does not fit ``contract.py`` (names, shapes, metadata)."""


class ModelInputError(ModelError, ValueError):
    """Arrays handed to a models function with the wrong shape or values."""
