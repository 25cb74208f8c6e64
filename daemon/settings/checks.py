"""Checks shared by the configuration's sections, and the error they raise.

The settings modules (``settings``, ``source_settings``, ``mqtt_settings``)
all import from here and never from each other's internals, so that a
section can live in its own module without an import cycle.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Final

from scotti.daemon.errors import DaemonError

EX_CONFIG: Final = 78  # sysexits.h: configuration error
_TOPIC_FORBIDDEN: Final = re.compile(r"[+#/\x00-\x1f\s]")
DEVICE_ID_MAX: Final = 64  # characters; a topic level, a client id, a file name
_DEVICE_ID: Final = re.compile(r"[A-Za-z0-9_.-]+")  # safe in topics, client ids and file names
TOPIC_PREFIX_MAX: Final = 128  # characters, all levels together


class ConfigError(DaemonError):
    """A setting that cannot be used; the message is one line naming it."""


def sanitise_device_id(name: str) -> str:
    """A host name made safe for one MQTT topic level (``pi@lab 2`` -> ``pi-lab-2``)."""
    cleaned = re.sub(r"[^A-Za-z0-9_.-]+", "-", name.split(".")[0]).strip("-").lower()
    return cleaned[:DEVICE_ID_MAX].strip("-") or "scotti"


def is_file(path: Path) -> bool:
    """``path.is_file()``, False (not an exception) for a name the OS cannot even look up."""
    try:
        return path.is_file()
    except (OSError, ValueError):  # ENAMETOOLONG, ELOOP, an embedded NUL
        return False


def shown(value: str, limit: int = 40) -> str:
    """``value`` for an error message: repr, cut to ``limit`` characters."""
    return repr(value) if len(value) <= limit else repr(value[:limit]) + f"... ({len(value)} chars)"


def _check_topic_level(value: str, what: str) -> str:
    if not value:
        msg = f"{what} must not be empty"
        raise ValueError(msg)
    if _TOPIC_FORBIDDEN.search(value):
        msg = f"{what} {shown(value)} must not contain '+', '#', '/', spaces or control characters"
        raise ValueError(msg)
    return value


def check_device_id(v: str) -> str:
    """A device id usable as one MQTT topic level, a client id and a file name."""
    _check_topic_level(v, "device id")
    if len(v) > DEVICE_ID_MAX or not _DEVICE_ID.fullmatch(v):
        msg = f"device id {shown(v)}: at most {DEVICE_ID_MAX} characters of A-Z a-z 0-9 _ . -"
        raise ValueError(msg)
    return v


def check_topic_prefix(v: str) -> str:
    """A topic prefix: one level or several (``site/a``), none empty or a wildcard."""
    if len(v) > TOPIC_PREFIX_MAX:
        msg = f"topic prefix {shown(v)}: at most {TOPIC_PREFIX_MAX} characters"
        raise ValueError(msg)
    for level in v.split("/"):
        if not level or _TOPIC_FORBIDDEN.search(level):
            msg = f"topic prefix {shown(v)}: levels must be non-empty, without + # or spaces"
            raise ValueError(msg)
    return v
