"""The event loop's exception handler: known noise of a dropped broker connection at debug.

aiomqtt registers paho's socket with the loop through ``call_soon_threadsafe``
(``add_reader``/``add_writer`` with the descriptor number taken at call time).
When the broker drops the connection between that call and its turn on the
loop, the callback meets a socket that is closed or already unregistered:
``KeyError: '9 is not registered'``, ``FileNotFoundError`` from the selector.
And when a connection dies while nothing awaits it, aiomqtt's disconnect future
holds an ``MqttError`` nobody retrieves. Both are after-effects of a
disconnect the publisher has already reported in one WARNING line; asyncio's
default handler would log each as an ERROR with a traceback. Here they go to
debug; anything else still reaches the default handler, as an ERROR.

paho logs the same disconnects at ERROR too ("failed to receive on socket:
[Errno 104] Connection reset by peer"); ``QuietPahoErrors`` turns those into
debug records on the daemon's MQTT logger.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any, Final

import aiomqtt

log = logging.getLogger(__name__)

_SOCKET_CALLS: Final = frozenset({"add_reader", "add_writer", "remove_reader", "remove_writer"})


def is_disconnect_noise(context: dict[str, Any]) -> bool:
    """Is this loop error an after-effect of a broker connection that went away?"""
    exc = context.get("exception")
    future = context.get("future")
    if isinstance(exc, aiomqtt.MqttError) and future is not None and not context.get("handle"):
        return True  # "Future exception was never retrieved": aiomqtt's disconnect future
    handle = context.get("handle")
    callback = getattr(handle, "_callback", None)
    name = getattr(callback, "__name__", "")
    return name in _SOCKET_CALLS and isinstance(exc, KeyError | ValueError | OSError)


def handle_loop_error(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
    if is_disconnect_noise(context):
        log.debug(
            "after a broker disconnect: %s (%r)", context.get("message"), context.get("exception")
        )
        return
    loop.default_exception_handler(context)


class QuietPahoErrors(logging.Filter):
    """paho's ERROR records (socket failures) at debug: the publisher reports each
    disconnect once, with its reason, as a WARNING."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.ERROR:
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
            return logging.getLogger().isEnabledFor(logging.DEBUG)
        return True


def install(loop: asyncio.AbstractEventLoop, mqtt_logger: logging.Logger) -> None:
    """The loop handler above, and the filter on the logger aiomqtt hands to paho."""
    loop.set_exception_handler(handle_loop_error)
    if not any(isinstance(f, QuietPahoErrors) for f in mqtt_logger.filters):
        mqtt_logger.addFilter(QuietPahoErrors())
