"""Real predictions for the output tests, and readers for what the outputs wrote.

``predictions`` runs a session through the daemon's own pipeline with the
tiny model (what ``scotti-daemon --replay`` does, without MQTT).
"""

from __future__ import annotations

import asyncio
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from scotti.daemon.frames.pipeline import Pipeline, Prediction
from scotti.daemon.input.sources import ReplaySource
from scotti.daemon.service.counters import Counters
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


def read_mcap(path: Path) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, str], list[Any]]:
    """topic -> [(log_time, decoded message)], topic -> schema name, metadata records."""
    from mcap import reader as mcap_reader

    messages: dict[str, list[tuple[int, Any]]] = {}
    schemas: dict[str, str] = {}
    classes: dict[int, Any] = {}
    with path.open("rb") as f:
        reader = mcap_reader.make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            assert schema is not None
            schemas[channel.topic] = schema.name
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                assert channel.message_encoding == "protobuf"
                if schema.id not in classes:
                    classes[schema.id] = protobuf_class(schema.name, schema.data)
                decoded = classes[schema.id].FromString(message.data)
            messages.setdefault(channel.topic, []).append((message.log_time, decoded))
        f.seek(0)
        metadata = list(mcap_reader.make_reader(f).iter_metadata())
    return messages, schemas, metadata


def lsl_on_this_host() -> None:
    """Find LSL outlets on this host without relying on multicast (CI containers may have
    none): liblsl reads the file named by LSLAPICFG the first time it is used, in this
    process and in a daemon started from it. Call it before pylsl is first used."""
    if "LSLAPICFG" in os.environ:
        return
    config = Path(tempfile.mkdtemp(prefix="scotti-lsl-")) / "lsl_api.cfg"
    config.write_text("[lab]\nKnownPeers = {127.0.0.1}\n")
    os.environ["LSLAPICFG"] = str(config)
