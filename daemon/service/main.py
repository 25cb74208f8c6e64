"""``scotti-daemon``: command line, settings, model check, then the service.

Exit status: 0 after a graceful stop (or the end of a replay, or of a scene
played ``--once``); 78 (EX_CONFIG) for every mistake on the command line or
in the settings (an unknown option, a bad value, a replay file that is not a
session or holds no packets), a model that does not fit the contract or a
recording that cannot be created, with one line on stderr and no traceback;
1 when the service fails while running.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from pathlib import Path
from typing import Any, NoReturn

from scotti.daemon.errors import DaemonError
from scotti.daemon.settings import EX_CONFIG, ConfigError, Settings, load_settings

PROG = "scotti-daemon"


class _Parser(argparse.ArgumentParser):
    """A mistake on the command line is one line and exit 78, as a bad setting in the
    config file is (argparse's own way: the usage, then exit 2)."""

    def error(self, message: str) -> NoReturn:
        print(f"{PROG}: usage error: {message} (see {PROG} --help)", file=sys.stderr)
        sys.exit(EX_CONFIG)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog=PROG,
        description="Insole stream -> pose, action and progress over MQTT. Every option can "
        "also be set in the --config TOML file or as SCOTTI_* environment variables "
        "(command line > environment > file > defaults).",
    )
    src = p.add_argument_group(
        "source: one insole pair (several: a [[devices]] table in the --config file)"
    )
    src.add_argument("--port", help="receiver serial device, e.g. /dev/ttyACM0")
    src.add_argument(
        "--replay", type=Path, metavar="FILE",
        help="replay a session file once, then exit (one cut short plays its whole records)",
    )  # fmt: skip
    src.add_argument(
        "--simulate", metavar="SCENE",
        help="a simulated board on a pty playing a scene (a shipped name such as demo, or a "
        "TOML path) in a loop until stopped; the board's sequence numbers and clock go on "
        "across each loop, so a --record of it reads as one session",
    )  # fmt: skip
    src.add_argument(
        "--once", action="store_true", default=None,
        help="with --simulate: play the scene once, then exit 0 once its last prediction "
        "is published",
    )  # fmt: skip
    src.add_argument("--speed", metavar="1|N|max", help="replay/simulate rate (default 1)")
    p.add_argument("--model", type=Path, metavar="PATH", help="ONNX step graph (default: shipped)")
    p.add_argument("--threads", metavar="N", help="onnxruntime threads (default 1)")
    p.add_argument("--broker", metavar="URL", help="mqtt://host[:port] (default localhost:1883)")
    p.add_argument("--tls-ca-file", type=Path, metavar="PEM", help="CA the broker must chain to")
    p.add_argument("--tls-cert-file", type=Path, metavar="PEM", help="client certificate")
    p.add_argument("--tls-key-file", type=Path, metavar="PEM", help="client certificate's key")
    p.add_argument(
        "--device-id", "--device", dest="device_id", metavar="ID",
        help="topic level for this device (default: the host name)",
    )  # fmt: skip
    p.add_argument("--topic-prefix", metavar="PREFIX", help="topic prefix (default scotti)")
    p.add_argument("--format", metavar="json|msgpack", help="payload encoding (default json)")
    p.add_argument("--pressure", action="store_true", default=None, help="publish pressure")
    p.add_argument(
        "--control", action="store_true", default=None,
        help="take requests on PREFIX/ID/cmd/...: record, mark events, reset the repetition "
        "count (off by default; docs/mqtt.md, Remote control)",
    )  # fmt: skip
    p.add_argument(
        "--record",
        type=Path,
        metavar="FILE|DIR",
        help="record the raw bytes to a session file, never over one that exists (exit 78): "
        "{time} in the name (the UTC start) or a directory gives a new file at every start",
    )
    out = p.add_argument_group("other outputs (need the [outputs] extra; see docs/outputs.md)")
    out.add_argument(
        "--record-mcap", type=Path, metavar="OUT.mcap",
        help="the Foxglove channels into an MCAP file, named as --record's ({time}, a directory)",
    )  # fmt: skip
    out.add_argument(
        "--foxglove", type=int, nargs="?", const=8765, metavar="PORT",
        help="serve the channels to Foxglove over WebSocket (default port 8765)",
    )  # fmt: skip
    out.add_argument("--lsl", action="store_true", default=None, help="Lab Streaming Layer")
    out.add_argument("--web", type=int, metavar="PORT", help="browser live view on PORT")
    out.add_argument(
        "--max-connections", type=int, metavar="N",
        help="connections each of the Foxglove and web servers takes at a time (default 64)",
    )  # fmt: skip
    p.add_argument(
        "--processes", type=int, metavar="N",
        help="share the [[devices]] among N worker processes (default 1; docs/performance.md)",
    )  # fmt: skip
    p.add_argument("--log-level", metavar="LEVEL", help="debug, info, warning, error")
    p.add_argument("--config", type=Path, metavar="FILE", help="TOML config file")
    return p


# argparse destination -> (section, field) in Settings; None section = top level.
_CLI_FIELDS: dict[str, tuple[str | None, str]] = {
    "port": ("source", "port"),
    "replay": ("source", "replay"),
    "simulate": ("source", "simulate"),
    "once": ("source", "once"),
    "speed": ("source", "speed"),
    "model": ("model", "path"),
    "threads": ("model", "threads"),
    "broker": ("mqtt", "broker"),
    "tls_ca_file": ("mqtt", "tls_ca_file"),
    "tls_cert_file": ("mqtt", "tls_cert_file"),
    "tls_key_file": ("mqtt", "tls_key_file"),
    "device_id": ("mqtt", "device_id"),
    "topic_prefix": ("mqtt", "topic_prefix"),
    "format": ("mqtt", "format"),
    "pressure": ("mqtt", "pressure"),
    "control": ("mqtt", "control"),
    "record": (None, "record"),
    "record_mcap": ("outputs", "record_mcap"),
    "foxglove": ("outputs", "foxglove"),
    "lsl": ("outputs", "lsl"),
    "web": ("outputs", "web"),
    "max_connections": ("outputs", "max_connections"),
    "log_level": (None, "log_level"),
    "processes": (None, "processes"),
}


def cli_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The options given on the command line, nested like ``Settings``."""
    out: dict[str, Any] = {}
    for dest, (section, name) in _CLI_FIELDS.items():
        value = getattr(args, dest)
        if value is None:
            continue
        if section is None:
            out[name] = value
        else:
            out.setdefault(section, {})[name] = value
    return out


def configure_logging(level: str, prefix: str = "") -> None:
    """``prefix``: a worker process's name before each of its lines (service/processes.py)."""
    fmt = prefix + "%(levelname)s %(name)s: %(message)s"
    if sys.stderr.isatty():  # journald stamps its own time
        fmt = "%(asctime)s " + fmt
    logging.basicConfig(level=level.upper(), format=fmt, stream=sys.stderr, force=True)
    if level != "debug":
        # paho's own records (every packet at debug); not its parent "scotti.daemon.mqtt",
        # which would silence the publisher's and the remote control's INFO lines too.
        logging.getLogger("scotti.daemon.mqtt.paho").setLevel(logging.WARNING)


def _fail(kind: str, message: str) -> int:
    print(f"{PROG}: {kind}: {message}", file=sys.stderr)
    return EX_CONFIG


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        settings: Settings = load_settings(cli_overrides(args), args.config)
        model_path = settings.model.resolved_path()
        settings.mqtt.tls_context()  # CA, certificate and key read now: a bad one stops here
    except ConfigError as exc:
        return _fail("config error", str(exc))
    configure_logging(settings.log_level)
    if settings.processes > 1 and len(settings.device_list()) > 1:
        from scotti.daemon.service.processes import supervise  # no model here: the workers load it

        return supervise(settings, model_path)
    if settings.processes > 1:
        logging.getLogger("scotti.daemon.service.processes").info(
            "processes = %d: one device, it runs in this process", settings.processes
        )

    # Imported here: onnxruntime takes a moment, and a config error should not wait.
    from scotti.daemon.service.app import Daemon
    from scotti.models.errors import ModelError
    from scotti.models.kv_contract import KV_GRAPH
    from scotti.models.kv_streaming import open_step_model

    try:  # the paper form's step graph, or a streaming-native one (its metadata says)
        runtime = open_step_model(model_path, threads=settings.model.threads)
    except ModelError as exc:
        return _fail("model error", str(exc))
    if runtime.graph not in ("step", KV_GRAPH):
        return _fail(
            "model error", f"{model_path.name} is a {runtime.graph} graph; give the step graph"
        )
    try:
        return asyncio.run(Daemon(settings, runtime).run())
    except DaemonError as exc:  # cannot start (a recording that cannot be created)
        return _fail("error", str(exc))
    except KeyboardInterrupt:  # a second Ctrl-C during the graceful stop
        return 130


if __name__ == "__main__":
    sys.exit(main())
