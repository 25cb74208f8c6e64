"""Real predictions for the output tests, and readers for what the outputs wrote.

``predictions`` runs a session through the daemon's own pipeline with the
tiny model (what ``scotti-daemon --replay`` does, without MQTT).
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from scotti.daemon.counters import Counters
from scotti.daemon.pipeline import Pipeline, Prediction
from scotti.daemon.sources import ReplaySource
from scotti.models.runtime import ScottiRuntime


def predictions(session: Path, model: Path) -> list[Prediction]:
    out: list[Prediction] = []

    async def go() -> None:
        pipeline = Pipeline(ReplaySource(session, speed="max"), ScottiRuntime(model), Counters())
        await pipeline.run(out.append, lambda _: None, asyncio.Event())

    asyncio.run(go())
    return out


def protobuf_class(name: str, data: bytes) -> Any:
    """The message class of a protobuf schema as MCAP and Foxglove carry it (a
    serialized FileDescriptorSet), built the way any generic reader builds it."""
    files = descriptor_pb2.FileDescriptorSet.FromString(data)
    pool = descriptor_pool.DescriptorPool()
    pending = list(files.file)
    while pending:  # add each file after the files it imports
        fd = pending.pop(0)
        try:
            pool.Add(fd)
        except TypeError:
            pending.append(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
