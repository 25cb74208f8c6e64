"""One session record's msgpack body to a dict, in bounded memory whatever it claims.

msgpack turns a few bytes into much memory: an empty array is one byte in the
file and 64 in Python, a declared array length is allocated before its items
arrive, and the C unpacker nests 1024 deep. A record therefore passes one of
two gates before anything is built from it:

- the fast gate, for what writers write all the time (packets, labels, source
  frames, events): a body of at most ``SMALL_BODY`` bytes unpacked with maps
  and arrays of at most ``FLAT_MAP_LEN``, kept when it is a flat map. Whatever
  such a body holds costs at most about 64 bytes of Python per byte of it;
- the shape check, for everything else (the header, a large source frame, any
  body the fast gate refused): a walk over the bytes that allocates nothing
  and stops at the first value over the limits below, then msgpack with the
  same limits.

Limits follow from what writers store. The largest record is an imported
session's source frame (2 x rows x cols float32, one bin value) or a packet
chunk (4 KiB off the serial port); the most complex is the header, whose
scene, subject and import provenance nest a few tables deep with a few
hundred values. Each limit is at least ten times what the project's own
writers store: tests/test_firmware_protocol_session_unpack.py reads the
headers the simulator and the importer write under a tenth of every limit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

import msgpack

# A source frame of a 1448 x 1448 vendor grid pair still fits; a longer length prefix
# is corruption, not data.
MAX_RECORD_LEN: Final = 16 << 20
# The fast gate: bodies up to this size whose maps and arrays hold at most
# FLAT_MAP_LEN entries; the records written per frame are a few KiB with 3-7 keys.
SMALL_BODY: Final = 64 << 10
FLAT_MAP_LEN: Final = 15


@dataclass(frozen=True)
class ShapeLimits:
    """What one record may hold, checked before msgpack builds anything from it."""

    # Containers within containers, the record's own map being 1: a header's tables
    # (scene -> insole -> ...) nest fewer than ten deep.
    depth: int = 32
    # Values (keys, items and the containers themselves): a header has a few hundred.
    # At ~64 bytes of Python each, a record costs at most ~8 MiB besides its
    # strings' and bytes' own length.
    values: int = 1 << 17
    # Items of one array, entries of one map: a header's longest list has ~100.
    container_len: int = 1 << 16
    # Bytes of one string (names, labels, an event's detail, a scene's text).
    str_len: int = 1 << 20


LIMITS: Final = ShapeLimits()


class OverLimitError(ValueError):
    """A record whose shape is over the limits (a msgpack bomb or a corrupt writer):
    ``at`` is the byte within the body where the check stopped."""

    def __init__(self, at: int, what: str) -> None:
        super().__init__(what)
        self.at = at
        self.what = what


class UndecodableError(ValueError):
    """A record that is not a msgpack map, or says it holds more bytes than it has."""


_CONTAINERS: Final = (dict, list)
_NOUN: Final = {"map": "a map", "array": "an array", "str": "a string", "bin": "a bin value"}
_SCALAR_SIZE: Final = {  # first byte -> bytes of the whole value, for fixed-size scalars
    0xC0: 1, 0xC2: 1, 0xC3: 1,  # nil, false, true
    0xCA: 5, 0xCB: 9,  # float 32, 64
    0xCC: 2, 0xCD: 3, 0xCE: 5, 0xCF: 9,  # uint 8..64
    0xD0: 2, 0xD1: 3, 0xD2: 5, 0xD3: 9,  # int 8..64
}  # fmt: skip
_SIZED: Final = {  # first byte -> (what, bytes of its length field)
    0xC4: ("bin", 1), 0xC5: ("bin", 2), 0xC6: ("bin", 4),
    0xD9: ("str", 1), 0xDA: ("str", 2), 0xDB: ("str", 4),
    0xDC: ("array", 2), 0xDD: ("array", 4),
    0xDE: ("map", 2), 0xDF: ("map", 4),
}  # fmt: skip


def unpack_record(body: bytes) -> dict[str, Any]:
    """A record's map. ``OverLimitError`` when its shape is over the limits,
    ``UndecodableError`` when it is not a whole msgpack map."""
    if 0 < len(body) <= SMALL_BODY and 0x80 <= body[0] <= 0x8F:  # a small fixmap
        try:
            record = msgpack.unpackb(
                body,
                raw=False,
                max_str_len=SMALL_BODY,
                max_bin_len=SMALL_BODY,
                max_array_len=FLAT_MAP_LEN,
                max_map_len=FLAT_MAP_LEN,
                max_ext_len=0,
            )
        except (ValueError, TypeError, msgpack.UnpackException):
            pass  # the shape check says what is wrong, or unpacks it with room to spare
        else:
            for value in record.values():
                if isinstance(value, _CONTAINERS):
                    break  # nested: the shape check walks it, as it walks the header
            else:
                return record  # type: ignore[no-any-return]
    return unpack_checked(body)


def unpack_checked(body: bytes) -> dict[str, Any]:
    """``unpack_record`` without the fast gate: the shape check, then msgpack."""
    check_shape(body)
    try:
        # unpackb's buffer is the body itself (max_buffer_size = its length).
        record = msgpack.unpackb(
            body,
            raw=False,
            max_str_len=LIMITS.str_len,
            max_bin_len=MAX_RECORD_LEN,
            max_array_len=LIMITS.container_len,
            max_map_len=LIMITS.container_len,
            max_ext_len=0,
        )
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise UndecodableError(str(exc)) from None  # a non-text key, invalid UTF-8
    if not isinstance(record, dict):  # check_shape saw a map: unreachable, kept for types
        raise UndecodableError("not a map")
    return record


def check_shape(body: bytes, limits: ShapeLimits = LIMITS) -> None:
    """Walk ``body`` as one msgpack map without building any value.

    ``OverLimitError`` at the first value past one of ``limits``;
    ``UndecodableError`` when a length runs past the body's end, a byte is no
    msgpack type this format uses (ext types), the top value is not a map or
    bytes follow it. Iterative, so no input can exhaust the stack, and linear
    in the values it walks.
    """
    end = len(body)
    if not body or not (0x80 <= body[0] <= 0x8F or body[0] in (0xDE, 0xDF)):
        raise UndecodableError("not a map")
    pending = [1]  # values still to read in each open container, outermost first
    pos = values = 0
    while pending:
        if not pending[-1]:
            pending.pop()
            continue
        pending[-1] -= 1
        if pos >= end:
            raise UndecodableError("ends inside a value")
        values += 1
        if values > limits.values:
            raise OverLimitError(pos, f"more than {limits.values} values in one record")
        first = body[pos]
        if first < 0x80 or first >= 0xE0:  # positive, negative fixint
            pos += 1
            continue
        if first in _SCALAR_SIZE:
            pos += _SCALAR_SIZE[first]
            if pos > end:
                raise UndecodableError("ends inside a number")
            continue
        if first < 0x90:
            what, length, head = "map", first & 0x0F, 1
        elif first < 0xA0:
            what, length, head = "array", first & 0x0F, 1
        elif first < 0xC0:
            what, length, head = "str", first & 0x1F, 1
        elif first in _SIZED:
            what, size = _SIZED[first]
            head = 1 + size
            if pos + head > end:
                raise UndecodableError("ends inside a length")
            length = int.from_bytes(body[pos + 1 : pos + head], "big")
        else:
            raise UndecodableError(f"byte 0x{first:02x} at {pos} is no type of this format")
        left = end - pos - head
        if what in ("str", "bin"):
            if length > left:
                raise UndecodableError(f"{_NOUN[what]} of {length} bytes with {left} left")
            if what == "str" and length > limits.str_len:
                raise OverLimitError(pos, f"a string of {length} bytes (at most {limits.str_len})")
            pos += head + length
            continue
        items = 2 * length if what == "map" else length
        if items > left:  # every item takes a byte at least
            raise UndecodableError(f"{_NOUN[what]} of {length} with {left} bytes left")
        if length > limits.container_len:
            msg = f"{_NOUN[what]} of {length} entries (at most {limits.container_len})"
            raise OverLimitError(pos, msg)
        if len(pending) > limits.depth:  # this container's own depth: the top map is 1
            raise OverLimitError(pos, f"containers nested deeper than {limits.depth}")
        pos += head
        pending.append(items)
    if pos != end:
        raise UndecodableError(f"{end - pos} bytes after the record's map")
