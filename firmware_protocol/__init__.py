"""The receiver board's wire protocol (PROTOCOL.md) and the session file format.

Sans-I/O: bytes in, packets out; numpy and msgpack only.
"""

from scotti.firmware_protocol.assembly import AssemblerCounters, FootFrame, FrameAssembler
from scotti.firmware_protocol.errors import (
    BadCobsError,
    BadCrcError,
    BadVersionError,
    DecodeError,
    MalformedError,
    PacketValueError,
    ProtocolError,
    SessionError,
    TooLongError,
    UnknownTypeError,
)
from scotti.firmware_protocol.framing import (
    DecoderCounters,
    StreamDecoder,
    decode_all,
    encode_packet,
    encode_packets,
)
from scotti.firmware_protocol.packets import (
    MAX_PACKET_LEN,
    VERSION,
    BoardStatus,
    Foot,
    FrameRows,
    InsoleStatus,
    Packet,
    frame_blocks,
    parse_packet,
)
from scotti.firmware_protocol.session import (
    LabelRecord,
    PacketRecord,
    Session,
    SessionHeader,
    SessionReader,
    SessionWriter,
    SourceFrameRecord,
    iter_records,
    read_session,
)
from scotti.firmware_protocol.wrap import Unwrapper, clock_delta_us, seq_delta

__all__ = [
    "MAX_PACKET_LEN",
    "VERSION",
    "AssemblerCounters",
    "BadCobsError",
    "BadCrcError",
    "BadVersionError",
    "BoardStatus",
    "DecodeError",
    "DecoderCounters",
    "Foot",
    "FootFrame",
    "FrameAssembler",
    "FrameRows",
    "InsoleStatus",
    "LabelRecord",
    "MalformedError",
    "Packet",
    "PacketRecord",
    "PacketValueError",
    "ProtocolError",
    "Session",
    "SessionError",
    "SessionHeader",
    "SessionReader",
    "SessionWriter",
    "SourceFrameRecord",
    "StreamDecoder",
    "TooLongError",
    "UnknownTypeError",
    "Unwrapper",
    "clock_delta_us",
    "decode_all",
    "encode_packet",
    "encode_packets",
    "frame_blocks",
    "iter_records",
    "parse_packet",
    "read_session",
    "seq_delta",
]
