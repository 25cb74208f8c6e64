"""A per-frame payload encoded once, its ``latency_ms`` written in at the last moment.

``latency_ms`` is meant to say how old the output is when it leaves the
daemon (docs/mqtt.md). Measured before the payload is built and encoded, it
leaves out that work; measured after, it cannot be inside the bytes. So the
payload is encoded once with a placeholder, cut around the placeholder's
value, and the value is filled in right before the bytes are handed to the
MQTT client: one small concatenation, no second serialisation.

JSON: the number after ``"latency_ms":`` up to the next comma. msgpack: the
8-byte big-endian float after the key (msgpack packs Python floats as
float64). A payload without the key is sent as it was encoded.
"""

from __future__ import annotations

import struct
from typing import Final, Literal, NamedTuple

from pydantic import BaseModel
from scotti.daemon.mqtt.schemas import encode

_JSON_KEY: Final = b'"latency_ms":'
_MSGPACK_KEY: Final = b"\xaalatency_ms\xcb"  # fixstr(10) "latency_ms", then float64
_FLOAT64: Final = struct.Struct(">d")


class LatencySlot(NamedTuple):
    """Encoded bytes around an open ``latency_ms`` value; ``fill(ms)`` closes it. A
    named tuple: three or four are made per prediction, a frozen dataclass costs more."""

    head: bytes  # up to and including the key
    tail: bytes | None  # after the value; None: no slot, ``head`` is the whole payload
    fmt: Literal["json", "msgpack"]

    @classmethod
    def encode(cls, payload: BaseModel, fmt: Literal["json", "msgpack"]) -> LatencySlot:
        return cls.cut(encode(payload, fmt), fmt)

    @classmethod
    def cut(cls, data: bytes, fmt: Literal["json", "msgpack"]) -> LatencySlot:
        """``data``, an encoded payload, cut around its ``latency_ms`` value."""
        if fmt == "json":
            at = data.find(_JSON_KEY)
            if at < 0:
                return cls(data, None, fmt)
            start = at + len(_JSON_KEY)
            end = data.find(b",", start)  # the stamp's fields follow latency_ms
            end = end if end >= 0 else data.find(b"}", start)
            return cls(data[:start], data[end:], fmt)
        at = data.find(_MSGPACK_KEY)
        if at < 0:
            return cls(data, None, fmt)
        start = at + len(_MSGPACK_KEY)
        return cls(data[:start], data[start + _FLOAT64.size :], fmt)

    def fill(self, latency_ms: float) -> bytes:
        """The payload with ``latency_ms`` (rounded to microseconds) in its place."""
        return self.filled(value_bytes(latency_ms, self.fmt))

    def filled(self, value: bytes) -> bytes:
        """The payload with ``value`` (``value_bytes``, same format) in its place: one
        prediction's messages take one value, encoded once."""
        if self.tail is None:
            return self.head
        return self.head + value + self.tail


def value_bytes(latency_ms: float, fmt: Literal["json", "msgpack"]) -> bytes:
    """``latency_ms``, rounded to microseconds, as it stands in a payload of ``fmt``."""
    value = round(latency_ms, 3)
    return repr(value).encode() if fmt == "json" else _FLOAT64.pack(value)
