"""Payloads for publisher tests, and a publisher run as a process of its own.

``python -m tests.support.publishing URL SECONDS [key=value ...]`` connects a
``Publisher`` to URL (settings from the key=value pairs), feeds it one
prediction every 1/16 s and a status change every second, prints ``ready``
once it has been running a second, and after SECONDS prints its stats as one
JSON line (with what health would say under ``pipeline.publish``): what a test
needs to measure the publisher's CPU from outside.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from typing import Literal

import numpy as np
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt import messages
from scotti.daemon.mqtt.publisher import Publisher
from scotti.daemon.mqtt.schemas import Info, Status
from scotti.daemon.service.counters import Counters
from scotti.daemon.settings import MqttSettings
from scotti.models.contract import ACTIONS, FRAME_COLS, FRAME_ROWS, NUM_ACTIONS, NUM_KEYPOINTS

SQUAT = ACTIONS.index("squat")


def info() -> Info:
    return Info(
        device_id="dev1",
        versions={"scotti": "0"},
        model={},
        keypoints=[],
        actions=[],
        pose_frame="test",
        frame_rate_hz=16.0,
        window=40,
        format="json",
        topics={},
        settings={},
        host_wall_ns=0,
    )


def status(state: Literal["online", "degraded", "offline"]) -> Status:
    return Status(
        state=state, reasons=[], source="connected", feet={}, warming=(0, 40), host_wall_ns=1
    )


def batch(seq: int) -> Prediction:
    """A prediction as the pipeline makes it (squat, halfway, one repetition), made now."""
    now = time.monotonic_ns()
    probs = np.zeros(NUM_ACTIONS, dtype=np.float32)
    probs[SQUAT] = 1.0
    return Prediction(
        seq=seq,
        left_seq=seq,
        right_seq=seq,
        device_clock_us=0,
        host_wall_ns=0,
        host_mono_ns=now,
        predicted_for_mono_ns=now,
        last_byte_mono_ns=now,
        pose=np.zeros((NUM_KEYPOINTS, 3), dtype=np.float32),
        action_probs=probs,
        action=SQUAT,
        progress=0.5,
        repetition=1,
        flags=(),
        inference_ms=0.0,
        counts=np.zeros((FRAME_ROWS, 2 * FRAME_COLS), dtype=np.uint16),
    )


async def _run(url: str, seconds: float, options: dict[str, str]) -> None:
    mqtt = MqttSettings(broker=url, device_id="dev1", **options)  # type: ignore[arg-type]
    pub = Publisher(mqtt, info(), will=status("offline"))
    stop = asyncio.Event()
    task = asyncio.create_task(pub.run(stop))
    start = time.monotonic()
    seq = 0
    said_ready = False
    while time.monotonic() - start < seconds:
        pub.submit(batch(seq))
        if seq % 16 == 0:
            pub.set_status(status("online" if seq % 32 else "degraded"))
        seq += 1
        if not said_ready and time.monotonic() - start >= 1.0:
            print("ready", flush=True)
            said_ready = True
        await asyncio.sleep(1 / 16)
    out = {
        "state": pub.state,
        "detail": pub.detail,
        "published": pub.stats.published,
        "connects": pub.stats.connects,
        "last_error": pub.stats.last_error,
        "health_publish": messages.health(Counters().snapshot(), pub, seconds).pipeline["publish"],
    }
    stop.set()
    try:
        await asyncio.wait_for(task, 5)
    except TimeoutError:
        out["stop"] = "timed out"
    print(json.dumps(out), flush=True)


def main(argv: list[str]) -> None:
    url, seconds, *rest = argv
    options = dict(item.split("=", 1) for item in rest)
    asyncio.run(_run(url, float(seconds), options))


if __name__ == "__main__":
    main(sys.argv[1:])
