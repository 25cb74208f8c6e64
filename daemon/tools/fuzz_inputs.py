"""The fuzzer's inputs and what each target must hold to.

Each ``make_*`` draws one input from a ``random.Random``: random bytes, or a
valid input mutated (cut, bit-flipped, bytes inserted, deleted, repeated), or
for the config loader a TOML file with the daemon's real keys and hostile
values. Each ``check_*`` runs one input through its target and raises on
anything the target must not do. The command (``fuzz``) draws a million of
them; the test suite draws them through Hypothesis (``st.randoms()``).
"""

from __future__ import annotations

import json
import random
import resource
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.daemon.settings import ConfigError, load_settings
from scotti.firmware_protocol.assembly import RESTART_GAP, FrameAssembler
from scotti.firmware_protocol.errors import DecodeError, PacketValueError, SessionError
from scotti.firmware_protocol.framing import StreamDecoder, encode_packet
from scotti.firmware_protocol.packets import BoardStatus, Foot, FrameRows, Packet
from scotti.firmware_protocol.pairing import Pairing
from scotti.firmware_protocol.session import (
    MAGIC,
    MAX_RECORD_LEN,
    SessionHeader,
    SessionWriter,
    read_session,
)
from scotti.firmware_protocol.wrap import seq_delta
from scotti.models.contract import FRAME_COLS, FRAME_ROWS, SAMPLE_BITS

_ROWS_PER_BLOCK: Final = 8


def _valid_stream() -> bytes:
    """Two frame pairs (seq wrapping 65535 -> 0) and a board status, as sent."""
    rng = np.random.default_rng(1)
    out = b""
    for seq in (65535, 0):
        for foot in (Foot.LEFT, Foot.RIGHT):
            counts = rng.integers(0, 4096, (FRAME_ROWS, FRAME_COLS), dtype=np.uint16)
            for start in range(0, FRAME_ROWS, _ROWS_PER_BLOCK):
                rows = counts[start : start + _ROWS_PER_BLOCK]
                block = FrameRows(
                    foot, seq, 4_294_000_000 + seq, FRAME_ROWS, FRAME_COLS, SAMPLE_BITS, start, rows
                )
                out += encode_packet(block)
    return out + encode_packet(BoardStatus(uptime_s=3))


VALID_STREAM: Final = _valid_stream()


def mutate(
    rnd: random.Random,
    seed: bytes,
    edits: int = 8,
    set_to: tuple[int, ...] = (0x00, 0xFF, 0x01),
    inserts: tuple[bytes, ...] = (),
) -> bytes:
    """``seed`` with 1-``edits`` edits: flips, set bytes, inserts, deletes, repeats, a cut.

    ``set_to`` are the values a set byte takes besides a random one; ``inserts``
    are chunks an insert may take instead of random bytes (a format's own
    hostile tokens). The defaults draw what the serial fuzz has always drawn.
    """
    data = bytearray(seed)
    for _ in range(rnd.randint(1, edits)):
        kind = rnd.randrange(6)
        at = rnd.randrange(len(data)) if data else 0
        if kind == 0 and data:
            data[at] ^= 1 << rnd.randrange(8)
        elif kind == 1 and data:
            data[at] = rnd.choice((*set_to, rnd.randrange(256)))
        elif kind == 2:
            chunk = rnd.randbytes(rnd.randint(1, 64))
            data[at:at] = rnd.choice((chunk, *inserts)) if inserts else chunk
        elif kind == 3:
            del data[at : at + rnd.randint(1, 64)]
        elif kind == 4:
            data[at:at] = data[at : at + rnd.randint(1, 600)]
        elif kind == 5:
            del data[at:]
    return bytes(data)


def _bytes(rnd: random.Random, seed: bytes, max_random: int) -> bytes:
    return rnd.randbytes(rnd.randint(0, max_random)) if rnd.random() < 0.3 else mutate(rnd, seed)


# --- decoder -----------------------------------------------------------------------------


def make_decoder_input(rnd: random.Random) -> tuple[bytes, list[int]]:
    cuts = [rnd.randint(1, 700) for _ in range(rnd.randint(0, 12))]
    return _bytes(rnd, VALID_STREAM, 4096), cuts


def check_decoder(case: tuple[bytes, list[int]]) -> None:
    """Only packets and DecodeErrors; bounded buffer; chunking changes nothing."""
    data, cuts = case
    expected = [p for p in StreamDecoder().feed(data) if not isinstance(p, DecodeError)]
    chunked = StreamDecoder()
    got: list[Packet] = []
    pos = 0
    for size in [*cuts, len(data)]:
        for item in chunked.feed(data[pos : pos + size]):
            seen: object = item  # typed as the decoder promises; checked as if it might not
            if not isinstance(seen, FrameRows | BoardStatus | DecodeError):
                msg = f"decoder returned {type(item).__name__}"
                raise AssertionError(msg)
            if not isinstance(item, DecodeError):
                got.append(item)
        assert chunked.pending <= chunked.max_encoded_len, "decoder buffer over its bound"
        pos += size
    assert got == expected, "chunking changed the packets"
    assert chunked.counters.bytes_in == len(data)


# --- assembler (and pairing) -------------------------------------------------------------


def _block(rnd: random.Random) -> FrameRows | None:
    rows, cols = (
        (FRAME_ROWS, FRAME_COLS) if rnd.random() < 0.8 else (rnd.randint(1, 40), rnd.randint(1, 30))
    )
    start = rnd.randrange(rows)
    count = rnd.randint(1, rows - start)
    seq = rnd.choice((rnd.randint(0, 8), rnd.randint(65530, 65535), rnd.randrange(65536)))
    clock = rnd.choice((rnd.randrange(2**32), 2**32 - 1, seq * 62_500))
    samples = np.full((count, cols), rnd.randrange(4096), dtype=np.uint16)
    foot = Foot.LEFT if rnd.random() < 0.5 else Foot.RIGHT
    try:
        return FrameRows(foot, seq, clock, rows, cols, SAMPLE_BITS, start, samples)
    except PacketValueError:
        return None  # not a packet the wire can carry


def make_blocks(rnd: random.Random) -> list[tuple[FrameRows, int]]:
    blocks = [(_block(rnd), rnd.randrange(10**12)) for _ in range(rnd.randint(0, 40))]
    return [(b, t) for b, t in blocks if b is not None]


def check_assembler(blocks: list[tuple[FrameRows, int]]) -> None:
    """Frames whole-shaped, none twice between restarts, nothing held unbounded;
    the daemon's pairing takes whatever comes out."""
    assembler = FrameAssembler()
    pairing = Pairing()
    emitted: set[tuple[int, int]] = set()
    newest: dict[int, int] = {}  # per foot, the newest seq emitted
    for block, t_ns in blocks:
        restarts = assembler.counters.restarts
        frames = assembler.push(block, t_ns)
        restarted = assembler.counters.restarts != restarts
        if restarted:  # a new board's seqs: those flushed now belong to the old one
            emitted.clear()
        for frame in frames:
            key = (int(frame.foot), frame.seq)
            last = newest.get(int(frame.foot))
            if last is not None and seq_delta(frame.seq, last) >= RESTART_GAP:
                # A jump ahead: seqs are modulo 65536, so after jumps adding up to a
                # wrap the same number is a new frame (the first million-input run
                # reported two such cases as findings; they were the check's).
                emitted -= {k for k in emitted if k[0] == key[0]}
            assert key not in emitted, f"frame {key} emitted twice"
            if not restarted:
                emitted.add(key)
                newest[key[0]] = frame.seq
            assert frame.counts.shape == (frame.rows, frame.cols)
            assert frame.complete == (not frame.rows_missing.any())
            for pair in pairing.push(frame):
                assert pair.counts.shape == (FRAME_ROWS, 2 * FRAME_COLS)
        assert assembler.in_progress <= 2 * assembler.max_in_progress, "frames held unbounded"
    for frame in assembler.flush():
        pairing.push(frame)
    for pair in pairing.flush():
        assert pair.counts.shape == (FRAME_ROWS, 2 * FRAME_COLS)
    assert assembler.in_progress == 0


# --- session files -----------------------------------------------------------------------


def session_seed(workdir: Path) -> bytes:
    """A small valid session file: header and three packet records."""
    path = workdir / "seed.scotti"
    if not path.exists():
        with SessionWriter(path, SessionHeader(source="recorded")) as writer:
            for i, chunk in enumerate([VALID_STREAM[:700], VALID_STREAM[700:], b"\x00\x55"]):
                writer.write_packet(1_000 + i, chunk)
    return path.read_bytes()


def make_session_bytes(rnd: random.Random, seed: bytes) -> bytes:
    draw = rnd.random()
    if draw < 0.15:
        return MAGIC + rnd.randbytes(rnd.randint(0, 512))
    if draw < 0.35:
        return session_with_bomb(rnd, seed)
    return _bytes(rnd, seed, 2048)


_VALUE_OF_KIND: Final = b"\x81\xa4kind"  # a map of one entry, key "kind": the value follows


def msgpack_bomb(rnd: random.Random) -> bytes:
    """A record body that makes much from little: containers nested deep, a length
    claimed far past the body, or many tiny containers (around the reader's value
    limit, session_unpack.LIMITS); one in fifty is the largest record of them (16 MiB,
    which the reader once took 1.2 GB to unpack)."""
    if rnd.random() < 0.02:
        return full_size_bomb(rnd)
    kind = rnd.randrange(3)
    if kind == 0:
        depth = rnd.choice((rnd.randint(2, 40), rnd.randint(1000, 5000), 100_000))
        opener = rnd.choice((b"\x91", b"\x81\xa0", b"\xdc\x00\x01"))  # [x], {"": x}, [x]
        return _VALUE_OF_KIND + opener * depth + b"\x90"
    if kind == 1:
        head = rnd.choice((b"\xdd", b"\xdf", b"\xdb", b"\xc6", b"\xdc", b"\xde", b"\xda", b"\xc5"))
        width = 4 if head in (b"\xdd", b"\xdf", b"\xdb", b"\xc6") else 2
        claim = rnd.choice(
            (2 ** (8 * width) - 1, 2 ** (8 * width - 1), rnd.randrange(2 ** (8 * width)))
        )
        return (
            _VALUE_OF_KIND + head + claim.to_bytes(width, "big") + rnd.randbytes(rnd.randint(0, 64))
        )
    inner = rnd.choice((1, 15, 255, 65535))
    outer = rnd.randint(1, max(1, (rnd.choice((20_000, 140_000)) // inner)))
    empty = rnd.choice((b"\x90", b"\x80"))
    return (
        _VALUE_OF_KIND
        + b"\xdd"
        + outer.to_bytes(4, "big")
        + (b"\xdd" + inner.to_bytes(4, "big") + empty * inner) * outer
    )


def full_size_bomb(rnd: random.Random) -> bytes:
    """A bomb as large as a record may be: many empty arrays in one, or in many."""
    n = MAX_RECORD_LEN - 64
    if rnd.random() < 0.5:  # one array of empty arrays
        return _VALUE_OF_KIND + b"\xdd" + n.to_bytes(4, "big") + b"\x90" * n
    # 255 arrays of 65535 empty arrays: no container over the length limit
    return _VALUE_OF_KIND + b"\xdc\x00\xff" + (b"\xdc\xff\xff" + b"\x90" * 65535) * 255


def session_with_bomb(rnd: random.Random, seed: bytes) -> bytes:
    """The seed session with a bomb record at a record boundary (the header's place
    too), its length prefix true or, now and then, a lie."""
    bounds, at = [], len(MAGIC)
    while at + 4 <= len(seed):
        bounds.append(at)
        at += 4 + int.from_bytes(seed[at : at + 4], "little")
    at = rnd.choice(bounds)
    body = msgpack_bomb(rnd)
    length = len(body) if rnd.random() < 0.9 else rnd.randrange(2**32)
    return seed[:at] + length.to_bytes(4, "little") + body + seed[at:]


# Reading one input may raise the process's peak RSS by this much at most: a bomb the
# reader unpacked would take gigabytes.
_PEAK_RISE_KIB: Final = 256 << 10


def _peak_rss_kib(reset: bool = False) -> int:
    """The process's peak RSS; ``reset``: from now on (Linux: clear_refs 5 sets the
    peak to the present, so each input is measured alone). Elsewhere ru_maxrss, which
    only grows: a finding shows once, the first input past the peak."""
    try:
        if reset:
            Path("/proc/self/clear_refs").write_text("5")
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def check_session(data: bytes, workdir: Path) -> None:
    """A Session or a SessionError, nothing else, in bounded memory."""
    path = workdir / "fuzzed.scotti"
    path.write_bytes(data)
    before = _peak_rss_kib(reset=True)
    try:
        session = read_session(path)
    except SessionError:
        session = None
    rise = _peak_rss_kib() - before
    assert rise < _PEAK_RISE_KIB, f"reading {len(data)} bytes raised the peak RSS {rise} KiB"
    for record in session.packets if session is not None else ():
        assert isinstance(record.data, bytes)


# --- config ------------------------------------------------------------------------------

_KEYS: Final[dict[str | None, tuple[str, ...]]] = {
    None: ("log_level", "stop_timeout_s", "record", "unknown"),
    "source": ("port", "replay", "simulate", "speed", "unknown"),
    "model": ("path", "threads", "unknown"),
    "mqtt": (
        "broker", "username", "password", "password_file", "client_id", "device_id",
        "topic_prefix", "format", "protocol", "keepalive_s", "message_expiry_s", "queue_size",
        "health_interval_s", "reconnect_max_s", "pressure", "pressure_downsample",
        "tls_ca_file", "tls_cert_file", "tls_key_file", "unknown",
    ),
}  # fmt: skip
_HOSTILE: Final = (
    "/dev/ttyACM0", "mqtt://h:0", "mqtts://:1", "garbage", "http://h", "mqtt://h:99999",
    "max", "0", "-1", "debug", "json", "x" * 10_000, "a/b", "+", "#", "", " ", "\u00e9", "..",
)  # fmt: skip


def _value(rnd: random.Random) -> Any:
    kind = rnd.randrange(7)
    if kind == 0:
        return rnd.choice(_HOSTILE)
    if kind == 1:
        return "".join(
            chr(rnd.choice((rnd.randrange(32, 127), rnd.randrange(0x10FFFF))))
            for _ in range(rnd.randint(0, 40))
        )
    if kind == 2:
        return rnd.choice((0, 1, -1, 2**63 - 1, -(2**63), rnd.randint(-100, 100_000)))
    if kind == 3:
        return rnd.choice(
            (0.0, -0.0, 1e308, -1e-308, float("inf"), float("nan"), rnd.uniform(-10, 400))
        )
    if kind == 4:
        return rnd.random() < 0.5
    if kind == 5:
        return [rnd.randint(0, 9) for _ in range(rnd.randint(0, 3))]
    return {"k": rnd.randint(0, 9)}


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return (
            "nan"
            if value != value
            else {float("inf"): "inf", float("-inf"): "-inf"}.get(value, repr(value))
        )
    if isinstance(value, int):
        return str(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"
    return json.dumps(str(value))  # TOML basic strings take JSON's escapes (astral: refused)


def make_toml(rnd: random.Random) -> str:
    if rnd.random() < 0.2:
        return mutate(rnd, b'[source]\nport = "/dev/x"\n[mqtt]\nbroker = "mqtt://h:1"\n').decode(
            "utf-8", "replace"
        )
    lines: list[str] = []
    for section, keys in _KEYS.items():
        chosen = rnd.sample(keys, rnd.randint(0, min(4, len(keys))))
        if section is not None and (chosen or rnd.random() < 0.1):
            lines.append(f"[{section}]")
        lines += [f"{key} = {_toml(_value(rnd))}" for key in chosen]
    return "\n".join(lines) + "\n"


def check_config(text: str, workdir: Path) -> None:
    """Settings, or one ConfigError of one line."""
    path = workdir / "fuzzed.toml"
    path.write_text(text, encoding="utf-8", errors="replace")
    try:
        load_settings({}, path)
    except ConfigError as exc:
        message = str(exc)
    else:
        return
    assert "\n" not in message, "config error of more than one line"
