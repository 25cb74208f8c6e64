"""``--foxglove``: a WebSocket client speaks the Foxglove protocol to the daemon's
server, subscribes to channels and decodes what comes."""

from __future__ import annotations

import asyncio
import contextlib
import json
import struct
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scotti.daemon.frames.pipeline import Prediction
from scotti.models.contract import ACTIONS, NUM_KEYPOINTS

from tests.support.outputs import predictions, protobuf_class
from tests.support.sessions import write_synthetic_session

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets.asyncio.client")

# What the Foxglove app offers: the SDK's protocol, then the older ws-protocol name.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # binary opcode: [op:1] [subscription id:4] [log time:8] [payload]


@pytest.fixture(scope="module")
def preds(tmp_path_factory: pytest.TempPathFactory, tiny_model_path: Path) -> list[Prediction]:
    session = write_synthetic_session(tmp_path_factory.mktemp("fg") / "s.scotti", frames=48)
    out = predictions(session.path, tiny_model_path)
    assert out
    return out


async def _json(ws: Any, op: str) -> dict[str, Any]:
    while True:
        msg = await asyncio.wait_for(ws.recv(), 5)
        if isinstance(msg, str) and (data := json.loads(msg))["op"] == op:
            return data  # type: ignore[no-any-return]


async def _session(preds: list[Prediction]) -> tuple[dict[str, Any], list[tuple[int, int, bytes]]]:
    from scotti.daemon.outputs.foxglove_out import FoxgloveOutput

    output = FoxgloveOutput(mcap=None, port=0)
    try:
        output.prediction("scotti", preds[0], 1.0)  # the JSON channels exist from the first message
        async with websockets.connect(
            f"ws://127.0.0.1:{output.port}", subprotocols=SUBPROTOCOLS
        ) as ws:
            channels: dict[str, Any] = {}
            while not {"/skeleton", "/action", "/pressure/left"} <= set(channels):
                for ch in (await _json(ws, "advertise"))["channels"]:
                    channels[ch["topic"]] = ch
            topics = ("/skeleton", "/action", "/pressure/left")
            subscribe = [{"id": i, "channelId": channels[t]["id"]} for i, t in enumerate(topics)]
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscribe}))
            got: list[tuple[int, int, bytes]] = []
            # No acknowledgement in the protocol: log the first prediction until each
            # subscription has delivered it, then the rest, which must all arrive.
            warm = preds[1]
            seen: set[int] = set()
            while len(seen) < len(topics):
                output.prediction("scotti", warm, 1.0)
                with contextlib.suppress(TimeoutError):
                    while len(seen) < len(topics):
                        msg = await asyncio.wait_for(ws.recv(), 0.2)
                        if isinstance(msg, bytes) and msg[0] == MESSAGE_DATA:
                            seen.add(struct.unpack_from("<I", msg, 1)[0])
            for p in preds[2:]:
                output.prediction("scotti", p, 1.0)
            while len(got) < len(topics) * (len(preds) - 2):
                msg = await asyncio.wait_for(ws.recv(), 10)
                if isinstance(msg, bytes) and msg[0] == MESSAGE_DATA:
                    sub, log_time = struct.unpack_from("<IQ", msg, 1)
                    if log_time != warm.host_wall_ns:
                        got.append((sub, log_time, msg[13:]))
            return channels, got
    finally:
        await output.close()


def test_client_subscribes_and_decodes(preds: list[Prediction]) -> None:
    channels, got = asyncio.run(_session(preds))
    # A lone device keeps the names a one-pair daemon always had: no id in them.
    assert {"/pressure/left", "/pressure/right", "/skeleton", "/action"} <= set(channels)
    assert not [t for t in channels if t.startswith("/scotti/")]
    skeleton = channels["/skeleton"]
    assert skeleton["encoding"] == "protobuf"
    assert skeleton["schemaName"] == "foxglove.SceneUpdate"
    import base64

    scene_class = protobuf_class(skeleton["schemaName"], base64.b64decode(skeleton["schema"]))
    by_sub: dict[int, list[tuple[int, bytes]]] = {0: [], 1: [], 2: []}
    for sub, log_time, payload in got:
        by_sub[sub].append((log_time, payload))
    expected = preds[2:]
    for sub in by_sub:
        assert [t for t, _ in by_sub[sub]] == [p.host_wall_ns for p in expected]
    for (_, payload), p in zip(by_sub[0], expected, strict=True):
        (entity,) = scene_class.FromString(payload).entities
        assert entity.frame_id == "pose"  # a lone device's pose frame, as before
        assert len(entity.spheres) == NUM_KEYPOINTS
        centres = [[s.pose.position.x, s.pose.position.y, s.pose.position.z]
                   for s in entity.spheres]  # fmt: skip
        np.testing.assert_allclose(centres, p.pose, atol=1e-6)
    for (_, payload), p in zip(by_sub[1], expected, strict=True):
        action = json.loads(payload)
        assert action["seq"] == p.seq
        assert list(action["probabilities"]) == list(ACTIONS)


async def _two_devices(
    preds: list[Prediction], mcap: Path
) -> tuple[dict[str, Any], dict[int, list[int]]]:
    """One server and one MCAP file for devices ``a`` and ``b``: a client subscribed to
    both devices' actions, and the seqs each subscription got (the warm-up left out)."""
    from scotti.daemon.outputs.foxglove_out import FoxgloveOutput

    output = FoxgloveOutput(mcap=mcap, port=0, devices=("a", "b"))
    try:
        for device in ("a", "b"):
            output.prediction(device, preds[0], 1.0)
        async with websockets.connect(
            f"ws://127.0.0.1:{output.port}", subprotocols=SUBPROTOCOLS
        ) as ws:
            channels: dict[str, Any] = {}
            while not {"/a/action", "/b/action", "/a/skeleton", "/b/skeleton"} <= set(channels):
                for ch in (await _json(ws, "advertise"))["channels"]:
                    channels[ch["topic"]] = ch
            topics = ("/a/action", "/b/action")
            subscribe = [{"id": i, "channelId": channels[t]["id"]} for i, t in enumerate(topics)]
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscribe}))
            warm = preds[1]
            seen: set[int] = set()
            while len(seen) < len(topics):
                for device in ("a", "b"):
                    output.prediction(device, warm, 1.0)
                with contextlib.suppress(TimeoutError):
                    while len(seen) < len(topics):
                        msg = await asyncio.wait_for(ws.recv(), 0.2)
                        if isinstance(msg, bytes) and msg[0] == MESSAGE_DATA:
                            seen.add(struct.unpack_from("<I", msg, 1)[0])
            for to_a, to_b in zip(preds[2:4], preds[4:6], strict=True):  # interleaved
                output.prediction("a", to_a, 1.0)
                output.prediction("b", to_b, 1.0)
            for p in preds[6:9]:  # then b falls silent: a's frames go on alone
                output.prediction("a", p, 1.0)
            got: dict[int, list[int]] = {0: [], 1: []}
            while sum(map(len, got.values())) < 7:
                msg = await asyncio.wait_for(ws.recv(), 10)
                if isinstance(msg, bytes) and msg[0] == MESSAGE_DATA:
                    sub, log_time = struct.unpack_from("<IQ", msg, 1)
                    if log_time != warm.host_wall_ns:
                        got[sub].append(json.loads(msg[13:])["seq"])
            return channels, got
    finally:
        await output.close()


def test_two_devices_one_server_and_one_file_channels_per_device(
    preds: list[Prediction], tmp_path: Path
) -> None:
    from tests.support.outputs import read_mcap

    assert len(preds) >= 9
    mcap = tmp_path / "two.mcap"
    channels, got = asyncio.run(_two_devices(preds, mcap))
    # Every topic carries its device; none is left with a lone device's name.
    assert all(t.startswith(("/a/", "/b/")) for t in channels), sorted(channels)
    assert {t.removeprefix("/a/") for t in channels if t.startswith("/a/")} >= {
        "pressure/left", "pressure/right", "skeleton", "pose", "action", "progress"
    }  # fmt: skip
    assert got[0] == [p.seq for p in preds[2:4] + preds[6:9]]  # a's to a's subscription
    assert got[1] == [p.seq for p in preds[4:6]]
    # The file: the same channels, each device's skeleton in its own pose frame.
    messages, schemas, metadata = read_mcap(mcap)
    assert schemas["/b/skeleton"] == "foxglove.SceneUpdate"
    in_file = {d: [m["seq"] for _, m in messages[f"/{d}/action"]] for d in ("a", "b")}
    assert [s for s in in_file["a"] if s > preds[1].seq] == got[0]
    assert [s for s in in_file["b"] if s > preds[1].seq] == got[1]
    frames = {m.entities[0].frame_id for d in "ab" for _, m in messages[f"/{d}/skeleton"]}
    assert frames == {"a/pose", "b/pose"}
    (devices,) = [m for m in metadata if m.name == "scotti.devices"]
    assert devices.metadata == {"a": "/a/", "b": "/b/"}


class _FullDisk:
    """Stands in for the MCAP writer at close: the disk filled up under the file."""

    def __init__(self, real: Any) -> None:
        self.real = real

    def close(self) -> None:
        self.real.close()
        raise OSError(28, "No space left on device")


def test_the_server_stops_and_frees_its_port_when_the_file_cannot_close(tmp_path: Path) -> None:
    import socket

    from scotti.daemon.outputs.foxglove_out import FoxgloveOutput

    output = FoxgloveOutput(mcap=tmp_path / "full.mcap", port=0)
    port = output.port
    assert port is not None
    output._writer = _FullDisk(output._writer)  # type: ignore[assignment]
    with pytest.raises(OSError, match="No space left"):
        asyncio.run(output.close())  # the file's error still reaches Outputs.close's log
    assert output.port is None
    # The port is free again, a restart can take it. The server's threads let go of it
    # a moment after ``stop`` returns (seen once in CI): give them 5 s; a server that
    # was never stopped holds it for good.
    deadline = time.monotonic() + 5
    while True:
        with socket.socket() as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind(("127.0.0.1", port))
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
        time.sleep(0.05)


def test_a_client_offering_only_the_older_subprotocol_is_refused_as_documented() -> None:
    """foxglove-sdk's server speaks ``foxglove.sdk.v1`` only and has no option to take a
    client that offers ``foxglove.websocket.v1`` alone (older Lichtblick, ws-protocol
    clients): HTTP 400, what docs/outputs.md tells such users to do about. Should a
    release of the SDK accept them, this fails and the docs change with it."""
    from scotti.daemon.outputs.foxglove_out import FoxgloveOutput
    from websockets.exceptions import InvalidStatus

    async def offer(subprotocols: list[str]) -> str | int:
        output = FoxgloveOutput(mcap=None, port=0)
        try:
            uri = f"ws://127.0.0.1:{output.port}"
            async with websockets.connect(uri, subprotocols=subprotocols) as ws:
                return str(ws.subprotocol)
        except InvalidStatus as exc:
            return int(exc.response.status_code)
        finally:
            await output.close()

    assert asyncio.run(offer(["foxglove.websocket.v1"])) == 400
    assert asyncio.run(offer(["foxglove.sdk.v1"])) == "foxglove.sdk.v1"
    assert asyncio.run(offer(SUBPROTOCOLS)) == "foxglove.sdk.v1"  # what Foxglove offers
