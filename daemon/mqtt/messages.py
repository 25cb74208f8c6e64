"""Building the MQTT payloads (``schemas``) from what the daemon knows.

Kept apart from ``schemas`` so that the public models depend on nothing of
the pipeline, and apart from ``app`` so that the life cycle reads short.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Literal, get_args

import numpy as np
from pydantic import BaseModel
from scotti.daemon.mqtt.schemas import (
    ACTION_NAMES,
    TOPICS,
    Action,
    FrameStamp,
    Health,
    Info,
    Latency,
    Pose,
    Pressure,
    Progress,
    Status,
    WithheldFlag,
)
from scotti.firmware_protocol.framing import DecoderCounters
from scotti.models.contract import (
    ACTIONS,
    FRAME_COLS,
    FRAME_RATE_HZ,
    KEYPOINTS,
    NO_ACTION,
    has_progress,
)
from scotti.models.input_checks import input_check_thresholds

if TYPE_CHECKING:
    from scotti.daemon.frames.pipeline import PipelineState, Prediction
    from scotti.daemon.mqtt.publisher import Publisher
    from scotti.daemon.settings import Settings
    from scotti.models.kv_streaming import StepModel

POSE_FRAME = "metres; origin on the floor under the mid-hip, z up, x forward, y to the left"


# Each per-frame payload's schema_version, from its model (the version lives there).
_VERSIONS: Final = {
    name: model.model_fields["schema_version"].default
    for name, model in (("pose", Pose), ("action", Action), ("progress", Progress))
}
_PRESSURE_VERSION: Final = Pressure.model_fields["schema_version"].default
_FRAME_MODELS: Final[dict[str, type[FrameStamp]]] = {
    "pose": Pose,
    "action": Action,
    "progress": Progress,
    "pressure": Pressure,
}


def frame_dicts(
    p: Prediction, latency_ms: float, pressure_downsample: int = 0
) -> list[tuple[str, dict[str, Any]]]:
    """pose, action, progress (and, when ``pressure_downsample``, pressure), same stamp:
    each as the plain dict its model (``schemas``) dumps, fields in the model's order.
    The publisher encodes these as they are, without a model instance per message
    (at 16 Hz per pair the models' construction was a visible share of the daemon);
    ``frame_payloads`` validates them into the models, and a test keeps both encodings
    the same bytes."""
    stamp: dict[str, Any] = {
        "seq": int(p.seq),
        "device_seq": {"left": int(p.left_seq), "right": int(p.right_seq)},
        "device_time_us": int(p.device_clock_us),
        "host_wall_ns": int(p.host_wall_ns),
        "host_mono_ns": int(p.host_mono_ns),
        "predicted_for_mono_ns": int(p.predicted_for_mono_ns),
        "latency_ms": round(latency_ms, 3),
        "flags": list(p.flags),
        "unfamiliar_score": None if p.unfamiliar_score is None else float(p.unfamiliar_score),
    }
    probs = p.action_probs.tolist()  # Python floats, float32's values exactly
    withheld = _withheld(p.withheld)
    # ACTION_NAMES is ACTIONS typed as the schema's literal (a test keeps them equal).
    action = ACTION_NAMES[p.action] if p.action != NO_ACTION else None
    confidence = float(probs[p.action]) if action is not None else 0.0
    defined = action is not None and has_progress(p.action) and math.isfinite(p.progress)
    progress = float(p.progress) if defined else None  # null while standing
    out: list[tuple[str, dict[str, Any]]] = [
        (
            "pose",
            {
                "schema_version": _VERSIONS["pose"],
                **stamp,
                "keypoints": np.asarray(p.pose, dtype=np.float64).tolist(),
            },
        ),
        (
            "action",
            {
                "schema_version": _VERSIONS["action"],
                **stamp,
                "action": action,
                "withheld": withheld,
                "confidence": confidence,
                "probabilities": dict(zip(ACTIONS, probs, strict=True)),
            },
        ),
        (
            "progress",
            {
                "schema_version": _VERSIONS["progress"],
                **stamp,
                "action": action,
                "progress": progress,
                "repetition": int(p.repetition),
                "withheld": withheld,
            },
        ),
    ]
    if pressure_downsample:
        out.append(("pressure", pressure_dict(stamp, p.counts, pressure_downsample)))
    return out


def frame_payloads(
    p: Prediction, latency_ms: float, pressure_downsample: int = 0
) -> list[tuple[str, BaseModel]]:
    """``frame_dicts`` as the schemas' models (validated): for the outputs beside MQTT."""
    return [
        (name, _FRAME_MODELS[name].model_validate(data))
        for name, data in frame_dicts(p, latency_ms, pressure_downsample)
    ]


_WITHHELD: Final[dict[str | None, WithheldFlag]] = {name: name for name in get_args(WithheldFlag)}


def _withheld(flag: str | None) -> WithheldFlag | None:
    """The pipeline's flag as the schema's literal (a test keeps OOD_FLAGS and it equal)."""
    return _WITHHELD.get(flag)


def downsample(counts: np.ndarray, k: int) -> np.ndarray:
    """Mean over k x k blocks (edges padded by repetition), as uint16."""
    if k == 1:
        return np.asarray(counts, dtype=np.uint16)  # no copy: the caller only reads it
    rows, cols = counts.shape
    padded = np.pad(counts, ((0, -rows % k), (0, -cols % k)), mode="edge").astype(np.float32)
    r, c = padded.shape
    blocks = padded.reshape(r // k, k, c // k, k).mean(axis=(1, 3))
    return np.asarray(np.rint(blocks), dtype=np.uint16)


def pressure_dict(stamp: Mapping[str, Any], counts: np.ndarray, k: int) -> dict[str, Any]:
    """``counts`` is the model input (H, 2W): left insole then right."""
    left = downsample(counts[:, :FRAME_COLS], k)
    right = downsample(counts[:, FRAME_COLS:], k)
    return {
        "schema_version": _PRESSURE_VERSION,
        **stamp,
        "rows": left.shape[0],
        "cols": left.shape[1],
        "downsample": k,
        "left": left.astype("<u2", copy=False).tobytes(),
        "right": right.astype("<u2", copy=False).tobytes(),
    }


def status(
    state: Literal["online", "degraded", "offline"],
    reasons: list[str],
    pipeline: PipelineState | None,
) -> Status:
    if pipeline is None:
        source: Literal["connected", "disconnected", "stopped"] = (
            "stopped" if state == "offline" else "disconnected"
        )
        return Status(
            state=state,
            reasons=reasons,
            source=source,
            feet={},
            warming=(0, 0),
            host_wall_ns=time.time_ns(),
        )
    return Status(
        state=state,
        reasons=reasons,
        source="stopped" if state == "offline" else pipeline.source,
        feet=dict(pipeline.feet),  # type: ignore[arg-type]
        warming=tuple(pipeline.warming),  # type: ignore[arg-type]
        host_wall_ns=time.time_ns(),
    )


def info(
    settings: Settings,
    runtime: StepModel,
    versions: dict[str, str],
    recording: Path | None = None,
) -> Info:
    """``recording``: the file actually recorded to (a new name when ``--record`` existed)."""
    from scotti.models.kv_streaming import KvStepRuntime  # loaded already: the model is open

    mqtt = settings.mqtt
    effective = settings.summary()
    if recording is not None:
        effective["record"] = str(recording)
        if settings.record is not None and recording != settings.record:
            effective["record_requested"] = str(settings.record)
    return Info(
        device_id=mqtt.device_id,
        versions=versions,
        model={
            "file": runtime.path.name,
            "sha256": runtime.sha256,
            "graph": runtime.graph,
            "window": runtime.window,
            "embed_dim": runtime.embed_dim,
            "threads": runtime.threads,
            "card": runtime.card,
            "ood": runtime.ood_info(),
            "progress_calibration": runtime.progress_calibration_info(),
            "input_checks": input_check_thresholds(),
            **(
                {"step_kind": runtime.step_kind, "receptive_field": runtime.receptive_field}
                if isinstance(runtime, KvStepRuntime)
                else {}
            ),
        },
        keypoints=list(KEYPOINTS),
        actions=list(ACTIONS),
        pose_frame=POSE_FRAME,
        frame_rate_hz=FRAME_RATE_HZ,
        window=runtime.window,
        format=mqtt.format,
        topics={name: mqtt.topic(name) for name in TOPICS},  # every payload schema's topic
        settings=effective,
        host_wall_ns=time.time_ns(),
    )


def _latency(summary: Mapping[str, Any] | None) -> Latency:
    """A ``LatencyRing.summary()`` as published: nulls until something was measured."""
    if not summary or not summary.get("n"):
        return Latency(p50_ms=None, p90_ms=None, p99_ms=None, max_ms=None)
    return Latency(
        p50_ms=float(summary["p50"]),
        p90_ms=float(summary["p90"]),
        p99_ms=float(summary["p99"]),
        max_ms=float(summary["max"]),
    )


def _total(value: Any) -> int:
    if isinstance(value, Mapping):
        return sum(int(v) for v in value.values())
    return int(value or 0)


def dropped_packets(decoder: Mapping[str, int] | None) -> int:
    """The decoder's own count of packets thrown away (its dict also counts good ones)."""
    return DecoderCounters(**decoder).errors if decoder else 0


def health(
    snapshot: Mapping[str, Any],
    publisher: Publisher,
    uptime_s: float,
    outputs_dropped: int = 0,
    outputs_errors: Mapping[str, int] | None = None,
) -> Health:
    """``snapshot`` is ``Counters.snapshot()``; the publisher adds what it counted, and
    ``outputs_dropped`` is this device's predictions the outputs beside MQTT (MCAP,
    Foxglove, LSL, web) dropped because they fell behind; ``outputs_errors`` how often
    each of them failed on this device's messages (logged once, counted from then on)."""
    stats = publisher.stats
    latency = snapshot.get("latency_ms", {})
    return Health(
        uptime_s=round(uptime_s, 3),
        host_wall_ns=time.time_ns(),
        host_mono_ns=time.monotonic_ns(),
        last_seq=stats.last_seq,
        frames_in={k: int(v) for k, v in snapshot.get("frames_in", {}).items()},
        bad_packets=dropped_packets(snapshot.get("bad_packets")),
        gaps=_total(snapshot.get("gaps")),
        predictions=_total(snapshot.get("predictions")),
        published=stats.published,
        dropped=stats.dropped,
        dropped_frames=_total(snapshot.get("dropped_frames")),
        source_reconnects=_total(snapshot.get("reconnects")),
        broker_reconnects=stats.reconnects,
        queue_depth=publisher.queue_depth,
        inference=_latency(latency.get("inference")),
        end_to_end=_latency(stats.latency_ms.summary()),
        pipeline={
            **snapshot,
            "publish": {
                "dropped_queue_full": stats.dropped_full,
                "dropped_stale": stats.dropped_stale,
                "dropped_error": stats.dropped_error,
                # The broker's outages: health reaches a subscriber only after one ends.
                "broker_outages": stats.outages,
                "broker_unreachable_s": round(publisher.unreachable_s, 3),
                "broker_last_error": stats.last_error,
                # A broker that takes messages without acknowledging them: QoS 1 ones in
                # flight now, and connections dropped for it (mqtt.ack_timeout_s).
                "unacknowledged": publisher.unacknowledged,
                "broker_not_acknowledging": stats.not_acknowledging,
                # QoS 1 publishes the broker refused (MQTT v5 reason code, e.g. its ACL).
                "refused": stats.refused,
                "last_refused": stats.last_refused,
                # Another client's status on this device's topic, replaced with ours.
                "status_restored": stats.status_restored,
            },
            # Under ``pipeline`` (free-form in the schema), not a top-level field: health's
            # schema forbids unknown fields, so a consumer validating against version 1
            # would refuse every health with a new one.
            "outputs": {
                "dropped_queue_full": outputs_dropped,
                "errors": dict(outputs_errors or {}),
            },
        },
    )
