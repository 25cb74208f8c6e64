"""A local MQTT broker: for trying the daemon, and the demo's, the bench's and the tests'.

From the command line, a broker in the foreground until Ctrl-C, for a first
try of ``scotti-daemon`` on a machine without one (a robot's host usually has
its own; on Debian ``apt install mosquitto`` starts one on port 1883)::

    python -m scotti.daemon.tools.local_broker [--port 1883] [--host 127.0.0.1]

It is mosquitto when installed, else the embedded amqtt of the ``[demo]``
extra (which speaks MQTT 3.1.1 only: the daemon then needs
``SCOTTI_MQTT_PROTOCOL=3.1.1``; the tool says so).

In code, ``Mosquitto`` is a throwaway mosquitto on 127.0.0.1:<free port>,
started from a generated config in a temporary folder; it can be stopped and
started again on the same port (the broker-outage tests need that). With
``tls`` (CA, certificate and key files) it also listens with TLS on
``tls_port``; the plain listener stays, for test subscribers.
``running_broker`` is either broker as an async context manager (the demo's).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, Self

from scotti.daemon.errors import DaemonError

MOSQUITTO_PATHS = ("mosquitto", "/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto")


def bridge_conf(name: str, remote: str, topics: Sequence[str] = ("scotti/#",)) -> list[str]:
    """mosquitto config lines bridging this broker's ``topics`` out to ``remote``
    (host:port): what docs/deploy.md shows for a site's broker."""
    lines = [
        f"connection {name}",
        f"address {remote}",
        *(f"topic {t} out 1" for t in topics),  # QoS up to 1; each message keeps its own
        "bridge_protocol_version mqttv50",  # properties (content type, expiry) go along
        "cleansession true",
        "try_private true",
        "notifications false",
        "restart_timeout 1 10",  # reconnect after 1 s, backing off to 10 s
        "keepalive_interval 10",
    ]
    return lines


class BrokerError(DaemonError):
    """mosquitto missing or not accepting connections."""


def find_mosquitto() -> str | None:
    for name in MOSQUITTO_PATHS:
        found = shutil.which(name)
        if found:
            return found
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


class Mosquitto:
    """``with Mosquitto() as broker: ... broker.port ... broker.stop(); broker.start()``."""

    def __init__(
        self,
        port: int | None = None,
        password: tuple[str, str] | None = None,
        tls: tuple[Path, Path, Path] | None = None,
        extra_conf: Sequence[str] = (),
        host: str = "127.0.0.1",
    ) -> None:
        exe = find_mosquitto()
        if exe is None:
            msg = "mosquitto not found on PATH or in /usr/sbin"
            raise BrokerError(msg)
        self.exe = exe
        self.host = host
        self.credentials = password  # (user, password) clients must give, or None
        self.port = port or free_port()
        self.tls = tls  # (CA file, server certificate, server key)
        self.tls_port = free_port() if tls else None
        self._dir = Path(tempfile.mkdtemp(prefix="scotti-mosquitto-"))
        self._dir.chmod(0o755)  # mosquitto started as root reads it as user "mosquitto"
        self.log_path = self._dir / "mosquitto.log"
        self.extra_conf = list(extra_conf)  # more config lines, e.g. a bridge (docs/deploy.md)
        self.conf = self._write_conf(password)
        self._proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    @property
    def tls_url(self) -> str:
        """``mqtts://localhost:<tls_port>`` (the name the test certificates carry)."""
        return f"mqtts://localhost:{self.tls_port}"

    def _write_conf(self, password: tuple[str, str] | None) -> Path:
        lines = [
            f"listener {self.port} {self.host}",
            "persistence false",
            "log_dest stderr",
            "log_type error",
            "log_type warning",
            "log_type notice",
            "connection_messages true",
            "max_queued_messages 10000",
            # Nagle on the broker's sockets holds small messages for a delayed ACK
            # (~40 ms): a subscriber of per-frame topics wants each one now.
            "set_tcp_nodelay true",
        ]
        if self.tls is not None:
            ca, cert, key = self.tls
            lines += [
                f"listener {self.tls_port} {self.host}",
                f"cafile {ca}",
                f"certfile {cert}",
                f"keyfile {key}",
            ]
        if password is None:
            lines.append("allow_anonymous true")
        else:
            pwfile = self._dir / "passwd"
            pwfile.write_text(f"{password[0]}:{password[1]}\n")
            subprocess.run(["mosquitto_passwd", "-U", str(pwfile)], check=True)
            pwfile.chmod(0o644)  # a throwaway test password; mosquitto must read it
            lines += ["allow_anonymous false", f"password_file {pwfile}"]
        conf = self._dir / "mosquitto.conf"
        conf.write_text("\n".join([*lines, *self.extra_conf]) + "\n")
        return conf

    def start(self, timeout: float = 10.0) -> None:
        if self.running:
            return
        log = self.log_path.open("ab")
        self._proc = subprocess.Popen(
            [self.exe, "-c", str(self.conf)], stdout=log, stderr=subprocess.STDOUT
        )
        log.close()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self._proc.poll() is not None:
                msg = f"mosquitto exited ({self._proc.returncode}): {self.log_tail()}"
                raise BrokerError(msg)
            try:
                with socket.create_connection((self.host, self.port), timeout=0.2):
                    return
            except OSError:
                time.sleep(0.05)
        self.stop()
        msg = f"mosquitto did not accept on port {self.port} within {timeout} s"
        raise BrokerError(msg)

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def stop(self) -> None:
        """Kill the broker (clients see a dropped connection, as on a crash)."""
        if self._proc is None:
            return
        if self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait(timeout=10)
        self._proc = None

    def log_tail(self, lines: int = 20) -> str:
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return " | ".join(text.splitlines()[-lines:])

    def close(self) -> None:
        self.stop()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


BrokerKind = Literal["auto", "mosquitto", "amqtt"]


@contextlib.asynccontextmanager
async def running_broker(
    kind: BrokerKind = "auto", port: int | None = None, host: str = "127.0.0.1"
) -> AsyncIterator[tuple[str, Literal["5", "3.1.1"]]]:
    """A broker on ``host``:``port`` (a free one when None) while the block runs;
    yields (its URL, the MQTT protocol it speaks). ``auto``: mosquitto when installed,
    else the embedded amqtt."""
    if kind == "mosquitto" or (kind == "auto" and find_mosquitto()):
        broker = Mosquitto(port=port, host=host)
        try:
            await asyncio.to_thread(broker.start)
            yield broker.url, "5"
        finally:
            broker.close()
        return
    try:
        from amqtt.broker import Broker  # the [demo] extra; speaks MQTT 3.1.1 only
    except ImportError:
        msg = "no broker: install mosquitto (apt install mosquitto) or pip install 'scotti[demo]'"
        raise BrokerError(msg) from None

    quiet = logging.getLogger("amqtt")  # its chatter would scribble over the demo's view
    quiet.addHandler(logging.NullHandler())
    quiet.propagate = False
    port = port or free_port()
    config: dict[str, Any] = {
        "listeners": {"default": {"type": "tcp", "bind": f"{host}:{port}"}},
        "plugins": {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}},
    }
    embedded = Broker(config)
    try:
        await embedded.start()
    except Exception as exc:  # amqtt wraps a busy port in its own error types
        msg = f"amqtt cannot listen on {host}:{port}: {exc}"
        raise BrokerError(msg) from None
    try:
        yield f"mqtt://{host}:{port}", "3.1.1"
    finally:
        await embedded.shutdown()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m scotti.daemon.tools.local_broker",
        description="An MQTT broker in the foreground until Ctrl-C, for trying scotti-daemon "
        "where none runs: mosquitto when installed, else the embedded amqtt ([demo] extra).",
    )
    p.add_argument("--port", type=int, default=1883, help="port to listen on (default 1883)")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0: every "
        "interface, without authentication)",
    )
    p.add_argument(
        "--broker",
        choices=("auto", "mosquitto", "amqtt"),
        default="auto",
        help="auto (default): mosquitto if installed, else the embedded amqtt",
    )
    return p


async def _serve(kind: BrokerKind, port: int, host: str) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    async with running_broker(kind, port, host) as (url, protocol):
        which = "mosquitto" if protocol == "5" else "amqtt, MQTT 3.1.1 only"
        print(f"local_broker: listening on {url} ({which}); Ctrl-C stops it", flush=True)
        hint = " SCOTTI_MQTT_PROTOCOL=3.1.1" if protocol == "3.1.1" else ""
        print(f"  try:{hint} scotti-daemon --simulate demo --broker {url}", flush=True)
        await stop.wait()


def _in_use(host: str, port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind((host, port))
        except OSError:
            return True
    return False


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if _in_use(args.host, args.port):
        print(
            f"local_broker: {args.host}:{args.port} is in use: a broker already running there? "
            "scotti-daemon can use that one as it is",
            file=sys.stderr,
        )
        return 1
    try:
        asyncio.run(_serve(args.broker, args.port, args.host))
    except BrokerError as exc:  # no broker installed, the port in use
        print(f"local_broker: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
