"""Checks shared by the configuration's sections, and the error they raise.

The settings modules (``settings``, ``settings.source``, ``settings.mqtt``)
all import from here and never from each other's internals, so that a
section can live in its own module without an import cycle.

What reaches the broker (topic prefix, device id, client id, user name) is checked
here against what brokers accept, so that a bad one stops the daemon at start with
exit 78 instead of failing at the broker on every reconnect.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Final

from scotti.daemon.errors import DaemonError

EX_CONFIG: Final = 78  # sysexits.h: configuration error
DEVICE_ID_MAX: Final = 64  # characters; a topic level, a client id, a file name
_DEVICE_ID: Final = re.compile(r"[A-Za-z0-9_.-]+")  # safe in topics, client ids and file names
TOPIC_PREFIX_MAX: Final = 128  # characters, all levels together
# MQTT carries a topic (and a client id, a user name) as UTF-8 behind a two-byte length.
TOPIC_BYTES_MAX: Final = 65_535
# The longest name the daemon puts after <prefix>/<device_id>/ (reply/<verb> with remote
# control); tests/test_daemon_topic_names.py holds every topic the daemon uses to it.
TOPIC_SUFFIX_MAX: Final = 32  # bytes
# The limits above keep every topic inside MQTT's, so a prefix or an id that passes its
# check never fails at the broker for its length: a prefix character takes at most four
# bytes of UTF-8, the device id is ASCII (the topic names test holds this sum to it).
LONGEST_TOPIC_BYTES: Final = 4 * TOPIC_PREFIX_MAX + 1 + DEVICE_ID_MAX + 1 + TOPIC_SUFFIX_MAX
# mosquitto drops what a client publishes to $SYS/... without a word, while the daemon
# would count it published; refused at every level so that no prefix reads like one.
_DOLLAR_WHY: Final = "brokers keep $-topics ($SYS) for themselves and drop what clients publish"


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


def _string_problem(value: str) -> str | None:
    """Why ``value`` cannot go to a broker as an MQTT string, or None.

    MQTT wants well-formed UTF-8 without NUL; mosquitto also refuses the control
    characters (C0, DEL, C1) and Unicode's non-characters, and closes the connection:
    the daemon would reconnect and fail forever. A lone surrogate is what Python makes
    of bytes that are not UTF-8 (a command-line argument, an environment variable).
    """
    for i, ch in enumerate(value):
        code = ord(ch)
        where = f"at position {i}"
        if 0xDC80 <= code <= 0xDCFF:  # os.fsdecode's stand-in for an undecodable byte
            return f"is not valid UTF-8 (byte 0x{code - 0xDC00:02x} {where})"
        if 0xD800 <= code <= 0xDFFF:
            return f"is not valid UTF-8 (lone surrogate U+{code:04X} {where})"
        if code < 0x20 or 0x7F <= code <= 0x9F:
            return f"holds a control character (U+{code:04X} {where})"
        if 0xFDD0 <= code <= 0xFDEF or (code & 0xFFFE) == 0xFFFE:
            return f"holds a Unicode non-character (U+{code:04X} {where}) brokers refuse"
    return None


def _topic_problem(value: str, extra: str = "") -> str | None:
    """Why ``value`` cannot stand in a topic the daemon publishes to, or None: an MQTT
    string without wildcards or spaces; ``extra``: characters refused besides."""
    problem = _string_problem(value)
    if problem is not None:
        return problem
    for i, ch in enumerate(value):
        if ch in "+#":
            return f"holds the wildcard {ch!r} at position {i}; a topic to publish to has none"
        if ch in extra or ch.isspace():
            return f"must not contain {ch!r} (at position {i})"
    return None


def check_mqtt_string(v: str, what: str) -> str:
    """A client id or a user name: something the broker takes as an MQTT string (room
    left for what the daemon appends to a client id: ``-<device id>-control``)."""
    problem = _string_problem(v)
    if problem is None and len(v.encode()) > TOPIC_BYTES_MAX - 2 * DEVICE_ID_MAX:
        problem = f"is {len(v.encode())} bytes of UTF-8; MQTT takes {TOPIC_BYTES_MAX} at most"
    if problem is not None:
        msg = f"{what} {shown(v)} {problem}"
        raise ValueError(msg)
    return v


def check_device_id(v: str) -> str:
    """A device id usable as one MQTT topic level, a client id and a file name."""
    if not v:
        msg = "device id must not be empty"
        raise ValueError(msg)
    problem = _topic_problem(v, "/")
    if problem is None and v.startswith("$"):
        problem = f"starts with '$': {_DOLLAR_WHY}"
    if problem is not None:
        msg = f"device id {shown(v)} {problem}"
        raise ValueError(msg)
    if len(v) > DEVICE_ID_MAX or not _DEVICE_ID.fullmatch(v):
        msg = f"device id {shown(v)}: at most {DEVICE_ID_MAX} characters of A-Z a-z 0-9 _ . -"
        raise ValueError(msg)
    return v


def check_topic_prefix(v: str) -> str:
    """A topic prefix: one level or several (``site/a``), none empty, none starting with
    ``$``, only characters every broker takes in a topic it is published to."""
    if not v:
        msg = "topic prefix must not be empty"
        raise ValueError(msg)
    if len(v) > TOPIC_PREFIX_MAX:
        msg = f"topic prefix {shown(v)}: at most {TOPIC_PREFIX_MAX} characters"
        raise ValueError(msg)
    problem = _topic_problem(v)
    if problem is None and "" in v.split("/"):
        problem = "has an empty level (a leading, trailing or doubled '/')"
    if problem is None and any(level.startswith("$") for level in v.split("/")):
        problem = f"has a level starting with '$': {_DOLLAR_WHY}"
    if problem is not None:
        msg = f"topic prefix {shown(v)} {problem}"
        raise ValueError(msg)
    return v
