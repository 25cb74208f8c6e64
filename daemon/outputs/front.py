"""The network outputs' own process: the web view's server and the Foxglove gate.

``python -m scotti.daemon.outputs.front`` is started by the daemon
(``front_process.FrontProcess``), never by hand. It gets its listening socket
and a message channel to the daemon (a SOCK_SEQPACKET socket pair) as
inherited descriptors, and its settings as JSON on stdin. Why a process:
every connection's descriptor, every byte sent to a browser and every
Python instruction that serves it are this process's, so neither a thousand
readers nor a flood of connections takes the daemon's descriptors (a
replugged receiver still opens) or its interpreter's time (the MQTT path is
not slowed). It ends when the daemon says so or when the daemon is gone
(the channel closes).

Every connection passes ``guard`` first (cap, Host, Origin, token). Then

- ``web``: the view's page, the device list and each device's Server-Sent
  Events feed; the daemon sends each event once, rendered, and this process
  copies it to every reader of that device. A reader has a short queue
  (``front_connection.CLIENT_QUEUE``) beyond what the kernel buffers: when
  it is full the oldest event is dropped, so a slow reader costs memory
  bounded by that and never holds up another;
- ``proxy``: the request head and then every byte both ways go to the
  Foxglove SDK's server, which listens on 127.0.0.1 at a port of its own.

Standard library only: it starts in a fraction of a second.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import html
import json
import logging
import resource
import socket
import struct
import sys
import urllib.parse
from collections.abc import Callable
from typing import Any, Final

from scotti.daemon.outputs import guard
from scotti.daemon.outputs.front_connection import Connection
from scotti.daemon.outputs.yield_cpu import yield_cpu_to_others

log = logging.getLogger("scotti.daemon.outputs.front")

COUNTERS_EVERY_S: Final = 0.25  # the counters go to the daemon at most this often
END_WAIT_S: Final = 1.0  # at the stop: for the readers to take what is buffered
DESCRIPTORS_SPARE: Final = 32  # kept free beyond the connections (listener, channel, ...)
OUT_OF_DESCRIPTORS: Final = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)
HTML: Final = "text/html; charset=utf-8"

# The daemon's messages: a kind byte, a device index (u16), the payload.
FRAME: Final = b"F"
STATUS: Final = b"S"
END: Final = b"E"
HEADER: Final = struct.Struct("<cH")


def cap_for_descriptors(wanted: int, per_connection: int) -> int:
    """Raise this process's descriptor limit as far as allowed; the cap that fits in it."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = wanted * per_connection + DESCRIPTORS_SPARE
    if soft != resource.RLIM_INFINITY and soft < need:
        new = need if hard == resource.RLIM_INFINITY else min(need, hard)
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (new, hard))
            soft = new
    if soft == resource.RLIM_INFINITY:
        return wanted
    return max(1, min(wanted, (soft - DESCRIPTORS_SPARE) // per_connection))


class Front:
    """One listening socket, its guard and what is behind it (``WebRoutes`` or a proxy)."""

    def __init__(self, config: dict[str, Any], listener: socket.socket, channel: socket.socket):
        self.loop = asyncio.get_running_loop()
        self.name: str = config["name"]
        self.listener = listener
        self.channel = channel
        per_connection = 2 if config["mode"] == "proxy" else 1
        wanted = int(config["max_connections"])
        rules = guard.Rules(
            max_connections=cap_for_descriptors(wanted, per_connection),
            bound_host=config["host"],
            allowed_hosts=tuple(config["allowed_hosts"]),
            allowed_origins=tuple(config["allowed_origins"]),
            token=config.get("token"),
        )
        if rules.max_connections < wanted:
            log.warning(
                "%s: at most %d connections (not %d): the descriptor limit allows no more",
                self.name,
                rules.max_connections,
                wanted,
            )
        self.rules = rules
        self.refusals = guard.RefusalLog(self.name, rules, self.loop.call_later)
        self.connections = 0
        self.open: set[Connection] = set()
        self.all_gone = asyncio.Event()
        self.dropped = 0  # events a slow reader never got (its queue was full)
        self.closing = asyncio.Event()
        self._counters_due = False
        self.routes: WebRoutes | None = None
        self.upstream: tuple[str, int] | None = None
        if config["mode"] == "web":
            self.routes = WebRoutes(self, config)
        else:
            self.upstream = (config["upstream_host"], int(config["upstream_port"]))

    # --- to the daemon ----------------------------------------------------------------
    def tell(self, message: dict[str, Any]) -> None:
        with contextlib.suppress(OSError):  # a full channel or a daemon gone: not ours
            self.channel.send(json.dumps(message).encode())

    def counters_changed(self) -> None:
        if not self._counters_due:
            self._counters_due = True
            self.loop.call_later(COUNTERS_EVERY_S, self.send_counters)

    def send_counters(self) -> None:
        self._counters_due = False
        self.tell(
            {
                "counters": {
                    "connections": self.connections,
                    "max_connections": self.rules.max_connections,
                    "refused": self.refusals.counts,
                    "dropped": self.dropped,
                }
            }
        )

    # --- connections ------------------------------------------------------------------
    async def accept(self) -> None:
        while True:
            try:
                conn, _ = await self.loop.sock_accept(self.listener)
            except OSError as exc:
                if exc.errno not in OUT_OF_DESCRIPTORS:
                    raise
                self.refused(guard.NO_DESCRIPTORS)
                await asyncio.sleep(0.05)  # the pending one waits in the backlog meanwhile
                continue
            if self.connections >= self.rules.max_connections:
                refuse_at_once(conn, guard.answer(guard.OVER_CAP))
                self.refused(guard.OVER_CAP)
                continue
            self.connections += 1
            self.counters_changed()
            try:
                await self.loop.connect_accepted_socket(lambda: Connection(self), conn)
            except OSError:
                conn.close()

    def refused(self, reason: str) -> None:
        self.refusals.refused(reason)
        self.counters_changed()

    def gone(self) -> None:
        self.connections -= 1
        self.counters_changed()
        if not self.connections:
            self.all_gone.set()

    async def from_daemon(self) -> None:
        while True:
            try:
                data = await self.loop.sock_recv(self.channel, 1 << 22)
            except OSError:
                data = b""
            if not data or data[:1] == END:
                return
            kind, device = HEADER.unpack_from(data)
            if self.routes is not None:
                self.routes.event(kind, device, data[HEADER.size :])


def refuse_at_once(conn: socket.socket, reply: bytes) -> None:
    """Answer and close without waiting on the client: a flood costs no descriptor."""
    with contextlib.suppress(OSError):
        conn.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            conn.recv(guard.HEAD_LIMIT)  # what it sent already: closing then sends no reset
        conn.send(reply)
    conn.close()


class WebRoutes:
    """The view's pages and feeds; every event comes from the daemon, rendered."""

    def __init__(self, front: Front, config: dict[str, Any]) -> None:
        self.front = front
        self.devices: list[str] = config["devices"]
        self.hello: list[bytes] = [h.encode() for h in config["hello"]]
        self.page: bytes = config["page"].encode()
        self.readers: list[set[Connection]] = [set() for _ in self.devices]
        self.status: dict[int, bytes] = {}
        self.state: dict[int, tuple[str, list[str]]] = {}

    def event(self, kind: bytes, device: int, payload: bytes) -> None:
        if device >= len(self.devices):
            return
        if kind == STATUS:
            status = json.loads(payload)
            data = status["sse"].encode()
            self.status[device] = data
            self.state[device] = (status["state"], list(status["reasons"]))
        else:
            data = payload
        for reader in self.readers[device]:
            reader.send(data)

    def leave(self, reader: Connection) -> None:
        assert reader.device is not None
        readers = self.readers[reader.device]
        readers.discard(reader)
        if not readers:
            self.front.tell({"watched": self.watched()})

    def watched(self) -> list[int]:
        return [i for i, readers in enumerate(self.readers) if readers]

    def route(self, conn: Connection, request: guard.Request) -> None:
        path = request.path
        if request.method != "GET":
            conn.respond("405 Method Not Allowed", "text/plain", b"GET only\n")
            return
        cookie = ""
        token = self.front.rules.token
        if token is not None and "token" in request.query:  # the page's feed sends it back
            cookie = f"Set-Cookie: {guard.TOKEN_COOKIE}={token}; HttpOnly; SameSite=Strict\r\n"
        lone = 0 if len(self.devices) == 1 else None
        name, _, rest = path.removeprefix("/devices/").partition("/")
        index = self.devices.index(name) if name in self.devices else None
        if path in ("/", "/index.html"):
            page = self.page if lone is not None else self.device_list_page()
            conn.respond("200 OK", HTML, page, cookie)
        elif path == "/events" and lone is not None:
            self.stream(conn, lone)
        elif path in ("/devices", "/devices.json"):
            body = json.dumps(self.device_list()).encode()
            conn.respond("200 OK", "application/json", body, cookie)
        elif path.startswith("/devices/") and index is not None:
            if path == f"/devices/{name}":  # the page's relative "events" needs the slash
                where = f"/devices/{urllib.parse.quote(name)}/"
                conn.respond("301 Moved Permanently", "text/plain", b"", f"Location: {where}\r\n")
            elif rest in ("", "index.html"):
                conn.respond("200 OK", HTML, self.page, cookie)
            elif rest == "events":
                self.stream(conn, index)
            else:
                conn.respond("404 Not Found", "text/plain", b"not found\n")
        elif path == "/events":
            body = b"several devices: each has its feed at /devices/<id>/events\n"
            conn.respond("404 Not Found", "text/plain", body)
        else:
            conn.respond("404 Not Found", "text/plain", b"not found\n")

    def stream(self, conn: Connection, device: int) -> None:
        first = not self.readers[device]
        conn.device = device
        self.readers[device].add(conn)
        if first:  # before the reader has its hello: the daemon renders for it from now on
            self.front.tell({"watched": self.watched()})
        assert conn.transport is not None
        conn.transport.write(
            b"HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\n"
            b"Cache-Control: no-store\r\nConnection: close\r\n\r\n" + self.hello[device]
        )
        if device in self.status:
            conn.send(self.status[device])

    def device_list(self) -> list[dict[str, Any]]:
        out = []
        for i, device in enumerate(self.devices):
            state, reasons = self.state.get(i, ("starting", []))
            view = f"/devices/{urllib.parse.quote(device)}/"
            out.append({"id": device, "state": state, "reasons": reasons, "view": view})
        return out

    def device_list_page(self) -> bytes:
        rows = "".join(
            f'<tr><td><a href="{html.escape(d["view"])}">{html.escape(d["id"])}</a></td>'
            f'<td class="{html.escape(d["state"])}">{html.escape(d["state"])}</td>'
            f"<td>{html.escape('; '.join(d['reasons']))}</td></tr>"
            for d in self.device_list()
        )
        return DEVICE_LIST.format(count=len(self.devices), rows=rows).encode()


# The list of devices (several only): refreshed every few seconds, each a link to its view.
DEVICE_LIST: Final = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta http-equiv="refresh" content="5">
<title>scotti devices</title>
<style>
  body {{ font: 14px system-ui, sans-serif; background: #111; color: #ddd; margin: 12px; }}
  a {{ color: #4c9be8; }} td, th {{ padding: 2px 12px 2px 0; text-align: left; }}
  .online {{ color: #6c6; }} .degraded {{ color: #e6b34c; }} .offline {{ color: #e66; }}
</style></head>
<body><h1 style="font-size: 16px">scotti live: {count} devices</h1>
<table id="devices"><tr><th>device</th><th>status</th><th>why</th></tr>{rows}</table>
</body></html>
"""


class ToDaemon(logging.Handler):
    """This process's log records go to the daemon's log, as the daemon's own."""

    def __init__(self, tell: Callable[[dict[str, Any]], None]) -> None:
        super().__init__()
        self._tell = tell

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._tell({"log": [record.levelno, record.name, self.format(record)]})
        except Exception:  # a record that cannot be formatted is not worth a crash
            self.handleError(record)


async def serve(config: dict[str, Any]) -> None:
    listener = socket.socket(fileno=int(config["listen_fd"]))
    channel = socket.socket(fileno=int(config["channel_fd"]))
    listener.setblocking(False)
    channel.setblocking(False)
    front = Front(config, listener, channel)
    root = logging.getLogger()
    root.handlers[:] = [ToDaemon(front.tell)]
    root.setLevel(logging.INFO)
    accepting = asyncio.create_task(front.accept())
    await front.from_daemon()
    accepting.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await accepting
    listener.close()
    for conn in list(front.open):
        conn.end()  # a feed after what it has queued; a page or a pipe at once
    if front.connections:  # what the readers still have buffered goes out, briefly
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(front.all_gone.wait(), END_WAIT_S)
    front.refusals.flush()
    front.send_counters()


def main() -> int:
    config = json.loads(sys.stdin.buffer.read())
    # The daemon's reading and publishing come first: when the CPU is short (a thousand
    # readers on a small host), this process waits, not the MQTT path.
    yield_cpu_to_others()
    asyncio.run(serve(config))
    return 0


if __name__ == "__main__":
    sys.exit(main())
