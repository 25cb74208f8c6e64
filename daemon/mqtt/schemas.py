"""The MQTT payloads, the daemon's public API: one pydantic model per topic.

Per-frame payloads (``pose``, ``action``, ``progress``, ``pressure``) share a
``FrameStamp`` so a consumer joins them on ``seq``. ``status``, ``info`` and
``health`` carry the schema version and the host's clocks.

Each payload has its own ``schema_version``, bumped when that payload changes
in a way a consumer must know about. ``action`` and ``progress`` are at 2
since model contract 2: the action ``standing`` (no repetitions), with
``progress`` null and ``repetition`` -1 while it holds. Every per-frame payload
went up by one when the model learnt to say what it does not know: the stamp's
``unfamiliar_score``, and ``withheld`` on ``action`` and ``progress``.

Run ``python -m scotti.daemon.mqtt.schemas --write`` to regenerate
``docs/schemas/*.schema.json`` and the table in ``docs/mqtt.md`` that links
them; ``--check`` fails when the committed files differ.
"""

from __future__ import annotations

import argparse
import base64
import json
import sys
from pathlib import Path
from typing import Annotated, Any, Final, Literal, TypeVar, get_args

import msgpack
import orjson
from pydantic import BaseModel, ConfigDict, Field

SCHEMA_VERSION: Final = 1  # of the payloads unchanged since the first release
CONTENT_TYPES: Final = {"json": "application/json", "msgpack": "application/msgpack"}

P = TypeVar("P", bound=BaseModel)
Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
# The model contract's actions (models.contract.ACTIONS), spelled out so that the
# JSON Schema lists them; a test keeps the two the same.
ActionName = Literal[
    "squat",
    "lunge",
    "step_up",
    "jump",
    "side_walking",
    "in_place_walking",
    "backward_walking",
    "walking",
    "standing",
]
ACTION_NAMES: Final[tuple[ActionName, ...]] = get_args(ActionName)
# Why a prediction's action is withheld (models.ood.OOD_FLAGS; a test keeps them equal).
WithheldFlag = Literal["unloaded", "out_of_range", "unfamiliar"]


def _version(n: int, why: str = "") -> Any:
    """The ``schema_version`` field of one payload: pinned, so a consumer's model of
    another version refuses it instead of misreading it."""
    text = f"{n}; bumped on a breaking change of this payload."
    return Field(default=n, description=f"{text} {why}".strip())


class _Payload(BaseModel):
    model_config = ConfigDict(
        extra="forbid", frozen=True, ser_json_bytes="base64", val_json_bytes="base64"
    )

    schema_version: int = _version(SCHEMA_VERSION)  # each payload pins its own below


class DeviceSeq(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    left: int = Field(description="Left insole frame sequence (u16, wraps).")
    right: int = Field(description="Right insole frame sequence (u16, wraps).")


class FrameStamp(_Payload):
    """Shared by every per-frame payload: join pose, action and progress on ``seq``."""

    seq: int = Field(description="Host count of paired frames since start; continuous.")
    device_seq: DeviceSeq
    device_time_us: int = Field(description="Left insole board clock of the frame (u32, wraps).")
    host_wall_ns: int = Field(description="Host wall clock (Unix ns) at inference.")
    host_mono_ns: int = Field(description="Host monotonic clock (ns) at inference.")
    predicted_for_mono_ns: int = Field(description="Host monotonic time the output is for.")
    latency_ms: float = Field(
        description="From the frame's last byte in to the bytes of this message handed to "
        "the MQTT client (encoding included; docs/mqtt.md)."
    )
    flags: list[str] = Field(
        description="Degradations, e.g. left_filled, rows_missing; and what the model does "
        "not know: unloaded (nobody on the insoles), out_of_range (not a plantar pressure "
        "map), unfamiliar (unlike the training data). With any of the last three the action, "
        "progress and repetition are withheld and the pose is not to be trusted."
    )
    unfamiliar_score: float | None = Field(
        default=None,
        description="Mahalanobis distance of the model's pooled representation from its "
        "training data; above info.model.ood.threshold the flags say unfamiliar. Null when "
        "the model is not calibrated (info.model.ood.calibrated false).",
    )


_V_OOD = "2 (pose, pressure) and 3 (action, progress) since the OOD flags."


class Pose(FrameStamp):
    schema_version: Literal[2] = _version(2, _V_OOD)
    keypoints: Annotated[list[Vec3], Field(min_length=19, max_length=19)] = Field(
        description="19 x [x, y, z] metres; order and frame in info.keypoints / info.pose_frame."
    )


_V2 = "2 since model contract 2: the action `standing`."


class Action(FrameStamp):
    schema_version: Literal[3] = _version(3, f"{_V2} {_V_OOD}")
    action: ActionName | None = Field(
        description="Most likely action (`standing`: weight on both feet, no repetition "
        "running), or null when withheld (see `withheld`)."
    )
    withheld: WithheldFlag | None = Field(
        default=None,
        description="Why `action` is null: the first of unloaded, out_of_range, unfamiliar "
        "in `flags`; null for a confident prediction. `probabilities` stay the model's own.",
    )
    confidence: float = Field(ge=0, le=1, description="Probability of `action`.")
    probabilities: dict[str, float] = Field(
        description="Probability of every action by name (the names of info.actions)."
    )


class Progress(FrameStamp):
    schema_version: Literal[3] = _version(3, f"{_V2} {_V_OOD}")
    action: ActionName | None = Field(description="The action this progress belongs to.")
    progress: float | None = Field(
        description="0..1 through the current repetition; null while `standing` (it runs "
        "no repetitions) or without an action."
    )
    repetition: int = Field(
        description="Repetitions of `action` counted so far; -1: none (`standing`, or no action). "
        "While withheld nothing is counted and the count resumes where it was."
    )
    withheld: WithheldFlag | None = Field(
        default=None, description="Why `action` and `progress` are null (as on `action`)."
    )


class Pressure(FrameStamp):
    """Optional (mqtt.pressure = true): downsampled counts for viewers."""

    schema_version: Literal[2] = _version(2, _V_OOD)
    rows: int = Field(description="Rows per foot after downsampling.")
    cols: int = Field(description="Columns per foot after downsampling.")
    downsample: int = Field(description="Block size averaged into one value.")
    left: bytes = Field(description="rows*cols uint16 LE, row-major (base64url in JSON).")
    right: bytes = Field(description="Same layout as `left`.")


class Status(_Payload):
    schema_version: Literal[1] = _version(1)
    state: Literal["online", "degraded", "offline"]
    reasons: list[str] = Field(description="Why degraded or offline; empty when online.")
    source: Literal["connected", "disconnected", "stopped"]
    feet: dict[str, Literal["ok", "silent"]] = Field(description="left/right: ok or silent.")
    warming: tuple[int, int] = Field(description="[frames in window, frames needed].")
    host_wall_ns: int = Field(description="When this status was composed (Unix ns).")


class Info(_Payload):
    schema_version: Literal[1] = _version(1)
    device_id: str
    versions: dict[str, str] = Field(description="scotti, python, onnxruntime, aiomqtt, ...")
    model: dict[str, Any] = Field(description="File, sha256, graph metadata and model card.")
    keypoints: list[str]
    actions: list[str]
    pose_frame: str
    frame_rate_hz: float
    window: int
    format: Literal["json", "msgpack"]
    topics: dict[str, str]
    settings: dict[str, Any] = Field(description="Effective settings, secrets left out.")
    host_wall_ns: int


class Latency(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    p50_ms: float | None
    p90_ms: float | None
    p99_ms: float | None
    max_ms: float | None


class Health(_Payload):
    schema_version: Literal[1] = _version(1)
    uptime_s: float
    host_wall_ns: int
    host_mono_ns: int
    last_seq: int | None = Field(description="seq of the newest published prediction.")
    frames_in: dict[str, int] = Field(description="Foot frames assembled, left and right.")
    bad_packets: int = Field(description="Packets the decoder rejected (CRC, framing, ...).")
    gaps: int = Field(description="Gaps in the frame sequence seen by pairing.")
    predictions: int
    published: int = Field(description="Predictions published.")
    dropped: int = Field(description="Predictions not published (queue full, stale, error).")
    dropped_frames: int = Field(description="Frames inference could not keep up with.")
    source_reconnects: int
    broker_reconnects: int
    queue_depth: int = Field(description="Predictions waiting for the broker now.")
    inference: Latency = Field(description="Model step time.")
    end_to_end: Latency = Field(description="Frame's last byte in to publish.")
    pipeline: dict[str, Any] = Field(description="Every pipeline counter (Counters.snapshot).")


# --- remote control (daemon/mqtt/control.py; docs/mqtt.md, "Remote control") ---------------
# One file name: no path, no dot first; {time} and {device} as in --record.
FILE_STEM: Final = r"^[A-Za-z0-9_{][A-Za-z0-9_.{}-]{0,63}$"


class _Request(BaseModel):
    """A request on ``cmd/<verb>``: a JSON object (an empty payload reads as ``{}``); an
    unknown field is refused, so a misspelt one is not silently ignored."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class RecordStart(_Request):
    """``cmd/record/start``: a session file (and an MCAP file) in ``mqtt.control_dir``."""

    name: str | None = Field(
        default=None,
        pattern=FILE_STEM,
        description="File name without suffix (A-Z a-z 0-9 _ . - and the placeholders "
        "{time}, {device}; at most 64, no path); default <device>-<UTC start>. A name that "
        "exists is refused, never overwritten.",
    )
    mcap: bool | None = Field(
        default=None,
        description="Also the Foxglove channels into <name>.mcap: true: required (refused "
        "without the [outputs] extra), false: no, absent: when the extra is installed.",
    )


class RecordStop(_Request):
    """``cmd/record/stop``: no fields; closes what is recording (started by record/start
    or by --record)."""


class EventMark(_Request):
    """``cmd/event/mark``: an event written into the recordings and echoed on ``event``."""

    label: str = Field(min_length=1, max_length=200, description="What happened, short.")
    detail: str = Field(default="", max_length=2000, description="More text, optional.")


class RepetitionsReset(_Request):
    """``cmd/repetitions/reset``: no fields; the repetition count starts again from 0."""


REQUESTS: Final[dict[str, type[_Request]]] = {
    "record/start": RecordStart,
    "record/stop": RecordStop,
    "event/mark": EventMark,
    "repetitions/reset": RepetitionsReset,
}


class Reply(_Payload):
    """The answer to every request; fields that do not apply to a verb are left out."""

    schema_version: Literal[1] = _version(1)
    ok: bool
    verb: str = Field(description="The verb asked for (cut to 64 characters).")
    reason: str | None = Field(default=None, description="Why not ok; absent when ok.")
    host_wall_ns: int = Field(description="When the request was done (Unix ns).")
    seq: int | None = Field(
        default=None, description="seq of the newest prediction when it was done."
    )
    session: str | None = Field(default=None, description="The session file (record/...).")
    mcap: str | None = Field(default=None, description="The MCAP file, if one (record/...).")
    seconds: float | None = Field(default=None, description="How long it recorded (stop).")
    events: int | None = Field(default=None, description="Events in the recording (stop).")
    written_to: list[str] | None = Field(
        default=None, description="Files the event went into (event/mark)."
    )
    note: str | None = Field(default=None, description="Something worth knowing, e.g. no MCAP.")


class Event(_Payload):
    """On ``event`` (QoS 1, not retained) for every ``event/mark`` done."""

    schema_version: Literal[1] = _version(1)
    label: str
    detail: str
    seq: int | None = Field(description="seq of the newest prediction when it was marked.")
    host_wall_ns: int
    host_mono_ns: int
    written_to: list[str] = Field(description="Files it went into (none when not recording).")


# Published only with remote control on; their schemas are in the docs with the others.
CONTROL_TOPICS: Final[dict[str, type[_Payload]]] = {"reply": Reply, "event": Event}

TOPICS: Final[dict[str, type[_Payload]]] = {
    "status": Status,
    "info": Info,
    "pose": Pose,
    "action": Action,
    "progress": Progress,
    "health": Health,
    "pressure": Pressure,
}


def encode(payload: BaseModel, fmt: Literal["json", "msgpack"]) -> bytes:
    if fmt == "json":
        return payload.model_dump_json().encode()
    data: bytes = msgpack.packb(payload.model_dump(mode="python"), use_bin_type=True)
    return data


def encode_dict(data: dict[str, Any], fmt: Literal["json", "msgpack"]) -> bytes:
    """A payload's plain dict (its model's dump, e.g. ``messages.frame_dicts``) encoded
    to the bytes ``encode`` makes of the model (a test keeps them the same): JSON by
    orjson (NaN as null, shortest float repr, as pydantic's serialiser; bytes as
    base64url, the payloads' ``ser_json_bytes``), about 2.5 times faster here than
    ``pydantic_core.to_json`` on the per-frame payloads."""
    if fmt == "json":
        return orjson.dumps(data, default=_base64url)
    packed: bytes = msgpack.packb(data, use_bin_type=True)
    return packed


def _base64url(value: object) -> str:
    if isinstance(value, bytes):
        return base64.urlsafe_b64encode(value).decode()
    msg = f"not a payload value: {type(value).__name__}"
    raise TypeError(msg)


def decode(model: type[P], data: bytes, fmt: Literal["json", "msgpack"]) -> P:
    if fmt == "json":
        return model.model_validate_json(data)
    return model.model_validate(msgpack.unpackb(data, raw=False, strict_map_key=False))


# --- documentation generator --------------------------------------------------
BEGIN: Final = "<!-- BEGIN GENERATED SCHEMAS (python -m scotti.daemon.mqtt.schemas --write) -->"
END: Final = "<!-- END GENERATED SCHEMAS -->"


def json_schemas() -> dict[str, str]:
    """Topic -> its JSON Schema as formatted text."""
    models: dict[str, type[BaseModel]] = {**TOPICS, **CONTROL_TOPICS}
    models |= {f"cmd/{verb}": model for verb, model in REQUESTS.items()}
    return {t: json.dumps(m.model_json_schema(), indent=2) + "\n" for t, m in models.items()}


def schema_file_name(topic: str) -> str:
    """The file under ``docs/schemas/`` that holds ``topic``'s schema."""
    return f"{topic.replace('/', '.')}.schema.json"


def render_doc_section() -> str:
    """One row per topic: a link to its schema file, its version and its fields."""
    lines = [BEGIN, "", "| topic | JSON Schema | schema_version | fields |", "|---|---|---|---|"]
    for topic, text in json_schemas().items():
        properties = json.loads(text)["properties"]
        version = properties.get("schema_version", {}).get("const", "-")
        fields = ", ".join(f"`{name}`" for name in properties if name != "schema_version")
        name = schema_file_name(topic)
        lines.append(f"| `{topic}` | [{name}](schemas/{name}) | {version} | {fields or '-'} |")
    lines += ["", END]
    return "\n".join(lines)


def render_doc(current: str) -> str:
    """``docs/mqtt.md`` with its generated section replaced (or appended)."""
    head, sep, rest = current.partition(BEGIN)
    if not sep:
        return current.rstrip("\n") + "\n\n" + render_doc_section() + "\n"
    _, sep_end, tail = rest.partition(END)
    if not sep_end:
        tail = ""
    return head + render_doc_section() + tail


def generated_files(docs: Path) -> dict[Path, str]:
    """Every generated file and its expected content."""
    files = {docs / "schemas" / schema_file_name(t): s for t, s in json_schemas().items()}
    mqtt_md = docs / "mqtt.md"
    current = mqtt_md.read_text(encoding="utf-8") if mqtt_md.exists() else "# MQTT API\n"
    files[mqtt_md] = render_doc(current)
    return files


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.daemon.mqtt.schemas")
    parser.add_argument("--docs", type=Path, default=Path("docs"), help="docs folder")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="regenerate the files")
    mode.add_argument("--check", action="store_true", help="fail if the files are stale")
    args = parser.parse_args(argv)
    stale = []
    for path, text in generated_files(args.docs).items():
        old = path.read_text(encoding="utf-8") if path.exists() else None
        if old == text:
            continue
        stale.append(str(path))
        if args.write:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
    if args.check and stale:
        print(f"schemas: stale, run with --write: {', '.join(stale)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
