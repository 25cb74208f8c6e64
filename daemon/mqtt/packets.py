"""MQTT PUBLISH packets at QoS 0, built whole, and publish properties packed once.

Per-frame messages are written to the socket by ``connection.Connection``
itself, several in one send (paho writes each message with a send of its
own). A QoS 0 PUBLISH is small enough to build here (MQTT 3.1.1 and 5,
section 3.3): the fixed header (type 3, no flags: QoS 0, not retained, not a
duplicate), the remaining length, the topic as a length-prefixed UTF-8
string, under MQTT 5 the properties, then the payload. QoS 0 has no packet
identifier, so nothing here can clash with the ones paho hands out.
"""

from __future__ import annotations

import struct
from typing import Final, Literal

from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from scotti.daemon.mqtt.schemas import CONTENT_TYPES

PUBLISH_QOS0: Final = 0x30
MAX_REMAINING: Final = 268_435_455  # four bytes of variable length integer
_TOPIC_LENGTH: Final = struct.Struct("!H")


def topic_header(topic: str, properties: Properties | None) -> bytes:
    """The variable header of every QoS 0 PUBLISH on ``topic``, made once: the topic
    name, then the packed properties; ``properties`` None under MQTT 3.1.1 (none)."""
    name = topic.encode()
    header = _TOPIC_LENGTH.pack(len(name)) + name
    if properties is None:
        return header
    packed: bytes = properties.pack()  # type: ignore[no-untyped-call]
    return header + packed


def fixed_header(remaining: int) -> bytes:
    """The PUBLISH type byte and the remaining length (a variable length integer)."""
    if remaining < 0x80:
        return bytes((PUBLISH_QOS0, remaining))
    if remaining < 0x4000:
        return bytes((PUBLISH_QOS0, remaining & 0x7F | 0x80, remaining >> 7))
    if remaining > MAX_REMAINING:
        msg = f"an MQTT packet holds at most {MAX_REMAINING} bytes, not {remaining}"
        raise ValueError(msg)
    out = bytearray((PUBLISH_QOS0,))
    while True:
        digit, remaining = remaining & 0x7F, remaining >> 7
        out.append(digit | 0x80 if remaining else digit)
        if not remaining:
            return bytes(out)


def packet(header: bytes, payload: bytes) -> bytes:
    """One whole QoS 0 PUBLISH: ``header`` from ``topic_header``, then ``payload``."""
    return fixed_header(len(header) + len(payload)) + header + payload


class PackedOnce(Properties):
    """Publish properties that never change, packed once (paho packs them on every
    publish: about 20 us each)."""

    def pack(self) -> bytes:
        packed: bytes | None = getattr(self, "_packed", None)
        if packed is None:
            packed = super().pack()  # type: ignore[no-untyped-call]
            object.__setattr__(self, "_packed", packed)  # paho checks the names it sets
        return packed


def publish_properties(fmt: Literal["json", "msgpack"], expiry_s: int | None) -> Properties:
    """MQTT v5 publish properties: content type, and expiry for what goes stale."""
    props = PackedOnce(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
    props.ContentType = CONTENT_TYPES[fmt]
    if expiry_s is not None:
        props.MessageExpiryInterval = expiry_s
    return props
