"""The Foxglove channels, written into an MCAP file and/or served live.

One ``foxglove.Context`` per output holds the channels; the MCAP writer and
the WebSocket server are sinks on it, so a file and a live Foxglove session
carry exactly the same topics, schemas and log times. A daemon of several
devices has one file and one server, and every device its own channels:
each topic below under ``/<device>`` (``/lab1/skeleton``), each frame id
under ``<device>/`` (``lab1/pose``: every person's pose frame has its own
origin). A lone device keeps the names below. Channels:

- ``/pressure/left``, ``/pressure/right``: ``foxglove.RawImage``, mono16 raw
  counts, 32 x 22 (toes up);
- ``/skeleton``: ``foxglove.SceneUpdate``, the pose with bones as lines and
  keypoints as spheres, in frame ``pose``;
- ``/pose``, ``/action``, ``/progress``: JSON, the MQTT payloads (plottable:
  ``/action.probabilities.squat``, ``/progress.progress``);
- ``/status``: JSON, the MQTT ``status`` (online / degraded / offline and why);
- ``/labels/skeleton``, ``/labels`` (``scotti session export`` of a labelled
  session): the ground truth, a grey skeleton beside the prediction and its
  action, progress and repetition.

Each JSON channel's schema is the payload's in the form Foxglove's parser
reads (``json_schema.foxglove_schema``: flat, no ``$ref`` or ``anyOf``), and a
field that is null is left out of the message, as that schema says. The file
starts with a metadata record ``scotti``: the model, its sha256 and what made
the file (the daemon's settings, or the exported session).

Every message is logged at the host wall time of its prediction (the
recording's own time in ``scotti session export``); the JSON messages carry
the device time and sequence beside it, like MQTT does, and the skeleton
entity carries them as metadata.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import foxglove
import numpy as np
from foxglove.channels import RawImageChannel, SceneUpdateChannel
from foxglove.messages import (
    Color,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)
from foxglove.websocket import WebSocketServer
from pydantic import BaseModel, Field
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.input.recording import RecordingError, new_file
from scotti.daemon.mqtt import messages
from scotti.daemon.mqtt.schemas import Status
from scotti.daemon.outputs import OutputError, device_prefix, guard
from scotti.daemon.outputs.front_process import FrontProcess, hidden_loopback, listen
from scotti.daemon.outputs.json_schema import foxglove_schema
from scotti.firmware_protocol.session import LabelRecord
from scotti.models.contract import ACTIONS, BONE_INDEX, FRAME_COLS, KEYPOINTS

POSE_FRAME_ID: Final = "pose"  # metres, origin under the mid-hip, z up, x forward
_LEFT: Final = Color(r=0.2, g=0.5, b=1.0, a=1.0)  # left side blue, right red: ROS/RViz habit
_RIGHT: Final = Color(r=1.0, g=0.3, b=0.2, a=1.0)
_MIDDLE: Final = Color(r=0.8, g=0.8, b=0.8, a=1.0)
_TRUTH: Final = Color(r=0.6, g=0.6, b=0.6, a=0.8)  # labels: grey, beside the prediction
_IDENTITY: Final = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
# The keys of the payloads' dict fields, each a property a Foxglove plot can pick.
DICT_KEYS: Final[dict[str, Sequence[str]]] = {"probabilities": ACTIONS, "feet": ("left", "right")}


class LabelMessage(BaseModel):
    """``/labels``: a label record of the session, as the channel carries it."""

    seq: int = Field(description="The frame's sequence (the left insole's, u16).")
    action: str | None = Field(description="The labelled action; absent on a transition.")
    progress: float | None = Field(description="0..1 through the repetition; absent if none.")
    repetition: int = Field(description="Repetition index; -1: none.")


def _side_colour(name: str) -> Color:
    return _LEFT if name.startswith("left") else _RIGHT if name.startswith("right") else _MIDDLE


def stamp(ns: int) -> Timestamp:
    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def pressure_image(counts: np.ndarray, ns: int, foot: str, prefix: str = "") -> RawImage:
    """One foot's raw counts as a 16-bit grey image (little-endian, row-major)."""
    data = np.ascontiguousarray(counts, dtype="<u2")
    rows, cols = data.shape
    return RawImage(
        timestamp=stamp(ns),
        frame_id=f"{prefix}insole_{foot}",
        width=cols,
        height=rows,
        encoding="mono16",
        step=2 * cols,
        data=data.tobytes(),
    )


def skeleton(p: Prediction, ns: int, device: str = "", prefix: str = "") -> SceneUpdate:
    """The pose as one scene entity: a line list of the bones and a sphere per keypoint."""
    metadata = {
        "seq": str(p.seq),
        "device_time_us": str(p.device_clock_us),
        "device_seq": f"{p.left_seq},{p.right_seq}",
    }
    if device:
        metadata["device"] = device
    return skeleton_of(p.pose, ns, metadata, frame_id=f"{prefix}{POSE_FRAME_ID}")


def skeleton_of(
    keypoints: np.ndarray,
    ns: int,
    metadata: dict[str, str],
    *,
    ground_truth: bool = False,
    frame_id: str = POSE_FRAME_ID,
) -> SceneUpdate:
    """``keypoints`` (19, 3) as an entity; the ground truth is drawn grey and thin."""
    kp = np.asarray(keypoints, dtype=np.float64)
    xyz = [(float(x), float(y), float(z)) for x, y, z in kp]
    points = [Point3(x=x, y=y, z=z) for x, y, z in xyz]
    bone_points = [points[i] for pair in BONE_INDEX for i in pair]
    colour = (lambda _name: _TRUTH) if ground_truth else _side_colour
    bone_colours = [colour(KEYPOINTS[int(i)]) for pair in BONE_INDEX for i in pair]
    size = 0.03 if ground_truth else 0.05
    spheres = [
        SpherePrimitive(
            pose=Pose(position=Vector3(x=x, y=y, z=z), orientation=_IDENTITY),
            size=Vector3(x=size, y=size, z=size),
            color=colour(name),
        )
        for name, (x, y, z) in zip(KEYPOINTS, xyz, strict=True)
    ]
    entity = SceneEntity(
        timestamp=stamp(ns),
        frame_id=frame_id,
        id="ground_truth" if ground_truth else "skeleton",
        frame_locked=True,
        metadata=[KeyValuePair(key=k, value=v) for k, v in metadata.items()],
        spheres=spheres,
        lines=[
            LinePrimitive(
                type=LinePrimitiveLineType.LineList,
                pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=_IDENTITY),
                thickness=0.01 if ground_truth else 0.02,
                scale_invariant=False,
                points=bone_points,
                colors=bone_colours,
            )
        ],
    )
    return SceneUpdate(entities=[entity])


class _DeviceChannels:
    """One device's channels, under ``/<prefix>`` (``prefix``: ``""`` or ``"<id>/"``)."""

    def __init__(self, context: foxglove.Context, device: str, prefix: str) -> None:
        self.context = context
        self.device = device
        self.prefix = prefix
        self.left = RawImageChannel(f"/{prefix}pressure/left", context=context)
        self.right = RawImageChannel(f"/{prefix}pressure/right", context=context)
        self.skeleton = SceneUpdateChannel(f"/{prefix}skeleton", context=context)
        self.json: dict[str, foxglove.Channel] = {}

    def prediction(self, p: Prediction, latency_ms: float) -> None:
        ns, prefix = p.host_wall_ns, self.prefix
        self.left.log(pressure_image(p.counts[:, :FRAME_COLS], ns, "left", prefix), log_time=ns)
        self.right.log(pressure_image(p.counts[:, FRAME_COLS:], ns, "right", prefix), log_time=ns)
        self.skeleton.log(skeleton(p, ns, self.device, prefix), log_time=ns)
        for name, payload in messages.frame_payloads(p, latency_ms):
            self.log_json(name, payload, ns)

    def log_json(self, name: str, payload: BaseModel, ns: int) -> None:
        channel = self.json.get(name)
        if channel is None:
            channel = json_channel(f"/{self.prefix}{name}", type(payload), self.context)
            self.json[name] = channel
        channel.log(json_message(payload), log_time=ns)


def json_channel(topic: str, model: type[BaseModel], context: foxglove.Context) -> foxglove.Channel:
    """A JSON channel whose schema Foxglove's parser reads (``json_schema``)."""
    schema = foxglove.Schema(
        name=model.__name__,
        encoding="jsonschema",
        data=json.dumps(foxglove_schema(model, DICT_KEYS)).encode(),
    )
    return foxglove.Channel(topic, schema=schema, message_encoding="json", context=context)


def json_message(payload: BaseModel) -> dict[str, Any]:
    """The payload as its channel's schema describes it: a null field is left out."""
    return payload.model_dump(mode="json", exclude_none=True)


class FoxgloveOutput:
    """``mcap``: a file to write; ``port``: serve live (0: any free port); ``devices``:
    the ids of the devices it carries (one: today's topic names; several: per device).

    The daemon's ``mcap`` is named as ``--record`` is (``recording.new_file``:
    ``{time}``, ``{device}``, a directory; a fixed name that exists is refused);
    ``overwrite`` (``scotti session export --force``) replaces it instead.
    ``metadata``: the ``scotti`` record written first (model, sha256, settings).

    Served live, clients connect to ``host:port`` through a gate of its own process
    (``front.py``: ``guard``'s cap, Host, Origin and token, then every byte both ways);
    the SDK's server itself listens on 127.0.0.1 at a port the gate alone is told.
    ``rules``: who may connect (default ``guard.Rules()``).
    """

    name = "foxglove"

    def __init__(
        self,
        *,
        mcap: Path | None,
        port: int | None,
        host: str = "127.0.0.1",
        overwrite: bool = False,
        devices: Sequence[str] = ("scotti",),
        metadata: Mapping[str, str] | None = None,
        rules: guard.Rules | None = None,
    ) -> None:
        self.context = foxglove.Context()
        if mcap is not None and not overwrite:
            named = devices[0] if len(devices) == 1 else "scotti"  # one file for all
            try:
                mcap = new_file(mcap, named, ".mcap")
            except RecordingError as exc:
                raise OutputError(f"--record-mcap: {exc}") from None
        self.mcap_path = mcap
        self.host = host
        self._writer: foxglove.mcap.MCAPWriter | None = None
        self._server: WebSocketServer | None = None
        self.gate: FrontProcess | None = None
        self._port: int | None = None
        self._upstream_host = "127.0.0.1"
        listener = listen(host, port, "--foxglove") if port is not None else None
        try:
            if mcap is not None:
                self._writer = foxglove.open_mcap(
                    mcap, context=self.context, allow_overwrite=overwrite
                )
            if listener is not None:
                self._port = listener.getsockname()[1]
                self._upstream_host = hidden_loopback()
                self._server = foxglove.start_server(
                    name="scotti-daemon", host=self._upstream_host, port=0, context=self.context
                )
        except Exception as exc:  # the library's own errors: file exists, port in use
            if listener is not None:
                listener.close()
            self._stop_sinks()
            target = f"MCAP file {mcap}" if self._writer is None and mcap else f"port {port}"
            msg = f"cannot open {target}: {exc}"
            raise OutputError(msg) from None
        if listener is not None and self._server is not None:
            base = rules or guard.Rules()
            rules = guard.Rules(
                max_connections=base.max_connections,
                bound_host=host,
                allowed_hosts=base.allowed_hosts,
                allowed_origins=base.allowed_origins,
                token=base.token,
            )
            config = {
                "mode": "proxy",
                "upstream_host": self._upstream_host,
                "upstream_port": self._server.port,
            }
            try:
                self.gate = FrontProcess.start("foxglove", listener, rules, config)
            except OutputError:
                self._stop_sinks()
                raise
        if metadata is not None:
            self.write_metadata("scotti", dict(metadata))
        self.devices = {
            d: _DeviceChannels(self.context, d, device_prefix(d, devices)) for d in devices
        }
        if len(devices) > 1:  # which topics are whose, for a reader of the file
            self.write_metadata(
                "scotti.devices", {d: f"/{device_prefix(d, devices)}" for d in devices}
            )
        self._truth: SceneUpdateChannel | None = None
        self._labels: foxglove.Channel | None = None

    @property
    def port(self) -> int | None:
        """Where clients connect (the gate's), ``None`` when not served (or stopped)."""
        return self._port if self._server is not None else None

    @property
    def sdk_address(self) -> tuple[str, int] | None:
        """Where the SDK's own server listens, reached only through the gate (a hidden
        loopback address: ``front_process.hidden_loopback``); None when not served."""
        if self._server is None:
            return None
        return self._upstream_host, self._server.port

    @property
    def counters(self) -> dict[str, Any]:
        """The gate's: connections now, the cap, refusals by reason (empty when not live)."""
        return dict(self.gate.counters) if self.gate is not None else {}

    def __str__(self) -> str:
        parts = [f"MCAP {self.mcap_path}"] if self.mcap_path else []
        if self._server is not None:
            parts.append(f"Foxglove WebSocket ws://{self.host}:{self._port}")
        if len(self.devices) > 1:
            parts.append(f"channels of {len(self.devices)} devices under /<id>/")
        return "foxglove: " + ", ".join(parts)

    def prediction(self, device: str, p: Prediction, latency_ms: float) -> None:
        self.devices[device].prediction(p, latency_ms)

    def status(self, device: str, status: Status) -> None:
        self.devices[device].log_json("status", status, status.host_wall_ns)

    def label(self, label: LabelRecord, ns: int) -> None:
        """A session's ground truth (export only): ``/labels/skeleton`` and ``/labels``."""
        if self._truth is None:
            self._truth = SceneUpdateChannel("/labels/skeleton", context=self.context)
            self._labels = json_channel("/labels", LabelMessage, self.context)
        assert self._labels is not None
        meta = {"seq": str(label.seq)}
        self._truth.log(skeleton_of(label.keypoints, ns, meta, ground_truth=True), log_time=ns)
        action = ACTIONS[label.action] if 0 <= label.action < len(ACTIONS) else None
        progress = float(label.progress) if np.isfinite(label.progress) else None
        message = LabelMessage(
            seq=label.seq, action=action, progress=progress, repetition=label.rep
        )
        self._labels.log(json_message(message), log_time=ns)

    def write_metadata(self, name: str, values: dict[str, str]) -> None:
        if self._writer is not None:
            self._writer.write_metadata(name, values)

    async def close(self) -> None:
        gate, self.gate = self.gate, None
        try:
            if gate is not None:  # first: no client is served by a stopped server
                await gate.close()
        finally:
            self._stop_sinks()

    def _stop_sinks(self) -> None:
        """Close the MCAP file and stop the server. The server stops even when the
        file's close fails (a full disk): its port is freed, and the file's error is
        raised after, for ``Outputs.close`` to report."""
        writer, self._writer = self._writer, None
        server, self._server = self._server, None
        try:
            if writer is not None:
                writer.close()
        finally:
            if server is not None:
                server.stop()
