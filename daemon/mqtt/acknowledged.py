"""Waiting for the broker: a publish acknowledged (or written), within ``ack_timeout_s``.

A broker that takes the connection but does not acknowledge a QoS 1 publish
(or take the bytes of QoS 0 ones) within ``ack_timeout_s`` is treated as
gone: the publisher drops the connection (its last will says offline) and
makes it again with backoff. Waiting costs nothing: one wait, woken by the
acknowledgement, the connection's end or the timeout.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import Any, TypeVar

from scotti.daemon.mqtt.connection import BrokerLostError, Connection

T = TypeVar("T")


class NotAcknowledgingError(BrokerLostError):
    """The broker did not answer a publish (or a subscribe) within the ack timeout."""


async def acknowledged(conn: Connection, publish: Awaitable[T], timeout_s: float) -> T:
    """Await ``publish`` (or a subscribe) on ``conn``; ``BrokerLostError`` as soon as the
    connection ends, ``NotAcknowledgingError`` when ``timeout_s`` passes first."""
    task = asyncio.ensure_future(publish)
    waiting: set[asyncio.Future[Any]] = {task, conn.lost}
    done, _ = await asyncio.wait(waiting, timeout=timeout_s, return_when=asyncio.FIRST_COMPLETED)
    if task in done and not task.cancelled():  # cancelled: the connection ended
        return task.result()
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    if conn.lost.done():
        raise BrokerLostError(conn.lost.result())
    msg = (
        f"not acknowledging: no answer to a publish within "
        f"{timeout_s:g} s ({conn.unacknowledged} unacknowledged)"
    )
    raise NotAcknowledgingError(msg)
