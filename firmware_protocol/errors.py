"""Errors of the wire protocol and the session files: one root, ``ProtocolError``.

A ``DecodeError`` describes one bad packet on the wire. The stream decoder
*returns* these as values (counted, then skipped) instead of raising them, so
garbage on the line can never stop a reader.
"""

from __future__ import annotations


class ProtocolError(Exception):
    """Root of every error this package raises or returns."""


class PacketValueError(ProtocolError, ValueError):
    """A packet built in Python with a field outside what the spec allows."""


class DecodeError(ProtocolError):
    """One received packet that was dropped; ``reason`` names its counter."""

    reason = "malformed"

    def __init__(self, detail: str) -> None:
        super().__init__(f"{self.reason}: {detail}")
        self.detail = detail


class BadCobsError(DecodeError):
    """The bytes between two delimiters are not valid COBS."""

    reason = "bad_cobs"


class TooLongError(DecodeError):
    """A run of bytes without a delimiter exceeded the longest legal packet."""

    reason = "too_long"


class BadCrcError(DecodeError):
    """The CRC-32 at the end of the packet does not match its contents."""

    reason = "bad_crc"


class BadVersionError(DecodeError):
    """A packet with a valid CRC but a protocol version this host does not speak."""

    reason = "bad_version"


class UnknownTypeError(DecodeError):
    """A valid packet of a type this host does not know (skipped, counted)."""

    reason = "unknown_type"

    def __init__(self, detail: str, packet_type: int) -> None:
        super().__init__(detail)
        self.packet_type = packet_type


class MalformedError(DecodeError):
    """A valid packet of a known type whose body breaks the spec."""

    reason = "malformed"


class SessionError(ProtocolError):
    """A session file that cannot be read or written; the message is one line."""
