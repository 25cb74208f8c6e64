"""The shared vector files: they match the encoder and decode to what they state.

The files are read here the way a firmware test would read them: comment
lines, ``# expect:`` lines of ``field=value``, then spaced hex.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scotti.firmware_protocol import cobs, vectors_gen
from scotti.firmware_protocol.errors import DecodeError
from scotti.firmware_protocol.framing import StreamDecoder
from scotti.firmware_protocol.packets import BoardStatus, FrameRows, Packet, parse_packet

FILES = sorted(vectors_gen.VECTORS_DIR.glob("*.hex"))
NAMES = [vector.name for vector in vectors_gen.build()]


def read_vector(path: Path) -> tuple[dict[str, str], bytes]:
    expect: dict[str, str] = {}
    hex_lines = []
    for line in path.read_text().splitlines():
        if line.startswith("# expect:"):
            for token in line.removeprefix("# expect:").split():
                key, _, value = token.partition("=")
                expect[key] = value
        elif not line.startswith("#") and line.strip():
            hex_lines.append(line)
    return expect, bytes.fromhex(" ".join(hex_lines))


def parse_value(text: str) -> object:
    if text in ("None", "True", "False"):
        return {"None": None, "True": True, "False": False}[text]
    return int(text, 0)


def field_of(packet: Packet, key: str) -> object:
    if key == "type":
        return packet.to_bytes()[1]
    if key == "samples_sum":
        assert isinstance(packet, FrameRows)
        return int(packet.samples.sum(dtype=np.int64))
    if key.startswith("samples["):
        assert isinstance(packet, FrameRows)
        row, col = (int(i) for i in key[8:-1].split(","))
        return int(packet.samples[row, col])
    value: object = packet
    for part in key.split("."):
        value = getattr(value, part)
    return value


def test_every_vector_has_a_file_and_the_files_match_the_encoder() -> None:
    assert [p.stem for p in FILES] == sorted(NAMES)
    for vector in vectors_gen.build():
        assert (vectors_gen.VECTORS_DIR / f"{vector.name}.hex").read_text() == vector.render()


@pytest.mark.parametrize("path", [p for p in FILES if p.stem != "stream_with_garbage"], ids=str)
def test_single_packet_vectors_decode_to_the_stated_fields(path: Path) -> None:
    expect, wire = read_vector(path)
    assert wire.endswith(b"\x00")
    assert wire.count(0) == 1
    packet = parse_packet(cobs.decode(wire[:-1]))
    assert StreamDecoder().feed(wire) == [packet]
    assert expect
    for key, value in expect.items():
        assert field_of(packet, key) == parse_value(value), key


def test_frame_vectors_follow_the_sample_rule() -> None:
    for name in ("frame_rows_left_full", "frame_rows_block"):
        _, wire = read_vector(vectors_gen.VECTORS_DIR / f"{name}.hex")
        block = FrameRows.from_bytes(cobs.decode(wire[:-1]))
        rows = np.arange(block.row_start, block.row_start + block.row_count)[:, None]
        expected = ((rows * 22 + np.arange(22)[None, :]) * 37) % 4096
        assert np.array_equal(block.samples, expected)


def test_stream_vector_decodes_to_the_stated_items_and_counters() -> None:
    expect, wire = read_vector(vectors_gen.VECTORS_DIR / "stream_with_garbage.hex")
    decoder = StreamDecoder()
    items = decoder.feed(wire)
    names = [
        item.reason
        if isinstance(item, DecodeError)
        else ("frame_rows" if isinstance(item, FrameRows) else "board_status")
        for item in items
    ]
    assert names == expect.pop("items").split(",")
    assert decoder.pending == int(expect.pop("pending"))
    for key, value in expect.items():
        assert getattr(decoder.counters, key) == int(value), key
    frames = [item for item in items if isinstance(item, FrameRows)]
    assert [(f.foot, f.seq, f.row_start, f.row_count) for f in frames] == [
        (0, 2, 0, 8),
        (0, 2, 8, 8),
        (0, 2, 16, 8),
        (0, 2, 24, 8),
        (1, 2, 0, 32),
    ]
    statuses = [item for item in items if isinstance(item, BoardStatus)]
    assert statuses == [vectors_gen.board_status()]
    slow = StreamDecoder()
    byte_by_byte = [x for i in range(len(wire)) for x in slow.feed(wire[i : i + 1])]
    assert [type(x) for x in byte_by_byte] == [type(x) for x in items]
    assert slow.counters == decoder.counters


def test_generator_command_checks_the_files(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "scotti.firmware_protocol.vectors_gen", "--check"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert vectors_gen.main(["--dir", str(tmp_path)]) == 0
    assert sorted(p.stem for p in tmp_path.glob("*.hex")) == sorted(NAMES)
    (tmp_path / "board_status.hex").write_text("# stale\n")
    assert vectors_gen.main(["--dir", str(tmp_path), "--check"]) == 1


def test_protocol_md_states_the_numbers_the_code_uses() -> None:
    from scotti.firmware_protocol.framing import MAX_ENCODED_LEN, encode_packet
    from scotti.firmware_protocol.packets import BOARD_STATUS_BODY_LEN, MAX_PACKET_LEN

    text = (vectors_gen.VECTORS_DIR.parent / "PROTOCOL.md").read_text()
    assert f"MAX_PACKET_LEN = {MAX_PACKET_LEN}" in text
    assert f"MAX_ENCODED_LEN = {MAX_ENCODED_LEN}" in text
    assert f"Body: exactly {BOARD_STATUS_BODY_LEN} bytes" in text
    assert encode_packet(vectors_gen.tiny_frame()).hex(" ") in text
    for path in FILES:
        assert f"`{path.name}`" in text
