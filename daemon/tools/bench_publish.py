"""Benchmark: the MQTT publisher's CPU per prediction, against a real mosquitto.

One ``Publisher`` per device, as the daemon runs them (one connection each),
all in this process's event loop; a throwaway mosquitto
(``local_broker.Mosquitto``) in its own process takes the messages. Every
``1 / --rate`` s each device is handed one prediction as the pipeline makes it
(pose, action probabilities, progress, flags, unfamiliar score, the pressure
frame it came from), so each publisher wakes once per prediction, as in the
daemon. The CPU of this process (``time.process_time``: every thread, the
event loop included, the broker not) over one repeat, divided by the
predictions published in it, is the cost of one prediction: encoding its
three messages (four with ``--pressure``), handing them to the socket, the
waits and wake-ups around them. The predictions of a repeat are made before
its clock starts. A measurement, never a test.

    python -m scotti.daemon.tools.bench_publish [--devices 32] [--rate 16] [--ticks 16]
        [--repeats 9] [--format json|msgpack] [--pressure] [--json]

To compare two versions of the publisher on one (busy) machine, run this file
against each in turn, several times, interleaved, and compare min and median,
e.g. with an old checkout's folders linked under ``/tmp/old/scotti/``::

    PYTHONPATH=/tmp/old python daemon/tools/bench_publish.py --json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt.publisher import Publisher
from scotti.daemon.mqtt.schemas import Info, Status
from scotti.daemon.settings import MqttSettings
from scotti.daemon.tools.local_broker import Mosquitto
from scotti.models.contract import (
    ACTIONS,
    FRAME_COLS,
    FRAME_RATE_HZ,
    FRAME_ROWS,
    NUM_ACTIONS,
    NUM_KEYPOINTS,
)

STANDING = ACTIONS.index("standing")
CONNECT_TIMEOUT_S = 20.0
DRAIN_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class Result:
    devices: int
    predictions: int  # published, all repeats
    dropped: int
    us_per_prediction: list[float]  # one per repeat

    def summary(self) -> dict[str, object]:
        runs = self.us_per_prediction
        return {
            "devices": self.devices,
            "predictions": self.predictions,
            "dropped": self.dropped,
            "us_min": round(min(runs), 1),
            "us_median": round(statistics.median(runs), 1),
            "us_runs": [round(r, 1) for r in runs],
        }


def make_prediction(rng: np.random.Generator, seq: int) -> Prediction:
    """One prediction with the shapes, dtypes and spread of the pipeline's."""
    now = time.monotonic_ns()
    logits = rng.normal(0.0, 2.0, NUM_ACTIONS).astype(np.float32)
    probs = np.exp(logits) / np.exp(logits).sum()
    action = int(np.argmax(probs))
    progress = float(rng.uniform()) if action != STANDING else float("nan")
    flags: tuple[str, ...] = ("left_filled",) if seq % 50 == 0 else ()
    pose = rng.normal(0.0, 0.4, (NUM_KEYPOINTS, 3)).astype(np.float32)
    counts = rng.integers(0, 4096, (FRAME_ROWS, 2 * FRAME_COLS), dtype=np.uint16)
    return Prediction(
        seq=seq,
        left_seq=seq & 0xFFFF,
        right_seq=(seq + 3) & 0xFFFF,
        device_clock_us=(seq * 62_500) & 0xFFFF_FFFF,
        host_wall_ns=time.time_ns(),
        host_mono_ns=now,
        predicted_for_mono_ns=now + 62_500_000,
        last_byte_mono_ns=now - 4_000_000,
        pose=pose,
        action_probs=probs.astype(np.float32),
        action=action,
        progress=progress,
        repetition=int(seq // 40) if action != STANDING else -1,
        flags=flags,
        inference_ms=0.5,
        counts=counts,
        unfamiliar_score=float(rng.uniform(0.5, 3.0)),
    )


def _info(fmt: Literal["json", "msgpack"]) -> Info:
    return Info(
        device_id="bench",
        versions={},
        model={},
        keypoints=[],
        actions=list(ACTIONS),
        pose_frame="bench",
        frame_rate_hz=FRAME_RATE_HZ,
        window=40,
        format=fmt,
        topics={},
        settings={},
        host_wall_ns=time.time_ns(),
    )


def _status(state: Literal["online", "offline"]) -> Status:
    return Status(
        state=state,
        reasons=[],
        source="connected",
        feet={"left": "ok", "right": "ok"},
        warming=(40, 40),
        host_wall_ns=time.time_ns(),
    )


async def _until(cond: object, within: float, what: str) -> None:
    deadline = time.monotonic() + within
    while not cond():  # type: ignore[operator]
        if time.monotonic() > deadline:
            msg = f"bench_publish: {what} not within {within:g} s"
            raise SystemExit(msg)
        await asyncio.sleep(0.01)


async def _bench(broker_url: str, args: argparse.Namespace) -> Result:
    publishers = [
        Publisher(
            MqttSettings(
                broker=broker_url,
                device_id=f"bench{i}",
                format=args.format,
                pressure=args.pressure,
            ),
            _info(args.format),
            will=_status("offline"),
        )
        for i in range(args.devices)
    ]
    for p in publishers:  # made before a repeat, a long one's last are past the expiry
        p.drop_stale = False
    stop = asyncio.Event()
    tasks = [asyncio.create_task(p.run(stop)) for p in publishers]
    rng = np.random.default_rng(42)
    period_s = 1.0 / args.rate
    runs: list[float] = []
    try:
        for p in publishers:
            p.set_status(_status("online"))
        await _until(
            lambda: all(p.state == "connected" for p in publishers), CONNECT_TIMEOUT_S, "connect"
        )
        await asyncio.sleep(0.5)  # the retained state out of the way
        seq = 0
        for repeat in range(args.repeats + 1):  # the first warms up, not counted
            ticks = [[make_prediction(rng, seq + t) for _ in publishers] for t in range(args.ticks)]
            seq += args.ticks
            published = sum(p.stats.published for p in publishers)
            cpu = time.process_time()
            start = time.monotonic()
            for t, tick in enumerate(ticks):
                for p, prediction in zip(publishers, tick, strict=True):
                    p.submit(prediction)
                await asyncio.sleep(max(0.0, start + (t + 1) * period_s - time.monotonic()))
            expected = published + len(ticks) * len(publishers)
            await _until(
                lambda e=expected: (
                    sum(p.stats.published + p.stats.dropped for p in publishers) >= e
                ),
                DRAIN_TIMEOUT_S,
                "publishing",
            )
            used = time.process_time() - cpu
            done = sum(p.stats.published for p in publishers) - published
            if repeat > 0:
                runs.append(used / max(1, done) * 1e6)
    finally:
        stop.set()
        await asyncio.wait_for(asyncio.gather(*tasks), DRAIN_TIMEOUT_S)
    return Result(
        devices=args.devices,
        predictions=sum(p.stats.published for p in publishers),
        dropped=sum(p.stats.dropped for p in publishers),
        us_per_prediction=runs,
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m scotti.daemon.tools.bench_publish",
        description="CPU per prediction of the MQTT publisher against a local mosquitto.",
    )
    parser.add_argument("--devices", type=int, default=32, help="publishers (pairs)")
    parser.add_argument("--rate", type=float, default=FRAME_RATE_HZ, help="predictions/s each")
    parser.add_argument("--ticks", type=int, default=16, help="predictions per device a repeat")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--format", choices=("json", "msgpack"), default="json")
    parser.add_argument("--pressure", action="store_true", help="the pressure topic too")
    parser.add_argument("--json", action="store_true", help="one JSON line, for scripts")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.devices < 1 or args.rate <= 0 or args.ticks < 1 or args.repeats < 1:
        print("bench_publish: --devices, --rate, --ticks and --repeats must be positive")
        return 2
    with Mosquitto() as broker:
        result = asyncio.run(_bench(broker.url, args))
    summary = result.summary()
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"{result.devices} publishers at {args.rate:g} Hz, {args.format}: "
            f"{summary['us_min']} us CPU per prediction (min of {len(result.us_per_prediction)}), "
            f"median {summary['us_median']}; {result.predictions} published, "
            f"{result.dropped} dropped"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
