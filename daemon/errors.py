"""Errors of the ``daemon`` room: one root, one-line messages.

``DaemonError`` is what a command line catches to print one line and exit
non-zero. Each module keeps its own subclass next to the code that raises it
(``ConfigError`` in config_checks, ``SourceError`` in sources, ...); foreign errors
(pyserial, OS, pydantic) are translated into them at the boundary.
"""

from __future__ import annotations


class DaemonError(Exception):
    """Root of every error raised by ``scotti.daemon``."""
