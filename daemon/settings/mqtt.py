"""The ``[mqtt]`` section: the broker, the client, the topics and what is published.

The broker connection may use TLS (``mqtts://``) with the system's CAs or
``mqtt.tls_ca_file``, and a client certificate (``tls_cert_file`` +
``tls_key_file``); the files are read at start, so a missing or broken one is a
one-line error then, not a reconnect loop later.

The broker password is a secret: it comes from ``SCOTTI_MQTT_PASSWORD`` or
``mqtt.password_file``, never from the TOML file, and is held as a
``SecretStr`` so that neither logs nor the retained ``info`` message show it.
"""

from __future__ import annotations

import socket
import ssl
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import urlsplit

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SecretStr,
    ValidationInfo,
    field_validator,
    model_validator,
)
from scotti.daemon.settings.checks import (
    ConfigError,
    check_device_id,
    check_mqtt_string,
    check_topic_prefix,
    is_file,
    sanitise_device_id,
    shown,
)


class MqttSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    broker: str = "mqtt://localhost:1883"  # mqtt://host[:port] or mqtts://host[:port] (TLS)
    username: str | None = None
    password: SecretStr | None = None  # only from SCOTTI_MQTT_PASSWORD
    password_file: Path | None = None  # file holding the password (first line)
    client_id: str | None = None  # default: scotti-daemon-<device_id>
    device_id: str = Field(default_factory=lambda: sanitise_device_id(socket.gethostname()))
    topic_prefix: str = "scotti"
    format: Literal["json", "msgpack"] = "json"
    protocol: Literal["5", "3.1.1"] = "5"  # 3.1.1 only for brokers without v5 (no properties)
    keepalive_s: Annotated[int, Field(ge=5, le=3600)] = 15
    message_expiry_s: Annotated[int, Field(ge=1, le=3600)] = 2  # pose/action/progress
    queue_size: Annotated[int, Field(ge=1, le=10_000)] = 32  # predictions waiting to publish
    health_interval_s: Annotated[float, Field(gt=0, le=3600)] = 5.0
    reconnect_max_s: Annotated[float, Field(gt=0, le=300)] = 5.0  # backoff ceiling
    # A publish not acknowledged (QoS 1) or not taken (QoS 0) by the broker within this:
    # the connection is dropped and made again (a broker that takes the connection and
    # then never answers is as good as gone).
    ack_timeout_s: Annotated[float, Field(gt=0, le=300)] = 5.0
    # While the broker stays away the log says so again this often (a WARNING each time).
    outage_warning_s: Annotated[float, Field(gt=0, le=3600)] = 15.0
    pressure: bool = False  # also publish downsampled pressure frames (the demo's view)
    pressure_downsample: Annotated[int, Field(ge=1, le=8)] = 2
    tls_ca_file: Path | None = None  # CA bundle (PEM) the broker's certificate must chain to
    tls_cert_file: Path | None = None  # client certificate (PEM), for brokers that want one
    tls_key_file: Path | None = None  # its private key (PEM); default: inside tls_cert_file
    # Remote control (daemon/mqtt/control.py, docs/mqtt.md "Remote control"): off unless asked
    # for. Requests on <prefix>/<id>/cmd/<verb> over a connection of its own, one at a
    # time, at most ``control_rate`` a second; beyond ``control_queue`` waiting, dropped.
    control: bool = False
    control_queue: Annotated[int, Field(ge=1, le=1000)] = 8
    control_rate: Annotated[float, Field(gt=0, le=1000)] = 20.0
    control_dir: Path = Path(".")  # where record/start writes (default: working directory)

    @field_validator("device_id")
    @classmethod
    def _device_id(cls, v: str) -> str:
        return check_device_id(v)

    @field_validator("topic_prefix")
    @classmethod
    def _prefix(cls, v: str) -> str:
        return check_topic_prefix(v)

    @field_validator("client_id", "username")
    @classmethod
    def _mqtt_string(cls, v: str | None, info: ValidationInfo) -> str | None:
        # Sent in CONNECT: one the broker refuses would fail every reconnect.
        return None if v is None else check_mqtt_string(v, str(info.field_name))

    @field_validator("broker")
    @classmethod
    def _broker(cls, v: str) -> str:
        _split_broker(v)
        return v

    @model_validator(mode="after")
    def _read_password_file(self) -> MqttSettings:
        if self.password is None and self.password_file is not None:
            try:
                secret = self.password_file.read_text(encoding="utf-8").splitlines()
            except OSError as exc:
                msg = f"cannot read password_file {self.password_file}: {exc.strerror}"
                raise ValueError(msg) from None
            object.__setattr__(self, "password", SecretStr(secret[0] if secret else ""))
        return self

    @model_validator(mode="after")
    def _tls_files(self) -> MqttSettings:
        given = [n for n in ("tls_ca_file", "tls_cert_file", "tls_key_file") if getattr(self, n)]
        if given and not self.tls:
            msg = f"{', '.join(given)} given but the broker URL is not mqtts://"
            raise ValueError(msg)
        if self.tls_key_file is not None and self.tls_cert_file is None:
            msg = "tls_key_file given without tls_cert_file"
            raise ValueError(msg)
        for name in given:
            path: Path = getattr(self, name)
            if not is_file(path):
                msg = f"{name}: file not found: {shown(str(path), 200)}"
                raise ValueError(msg)
        return self

    @model_validator(mode="after")
    def _control_dir(self) -> MqttSettings:
        if self.control and not self.control_dir.is_dir():
            msg = f"control_dir: not a directory: {shown(str(self.control_dir), 200)}"
            raise ValueError(msg)
        return self

    def tls_context(self) -> ssl.SSLContext | None:
        """The TLS context for ``mqtts://`` (None for ``mqtt://``); ``ConfigError`` if the
        CA, certificate or key file cannot be used."""
        if not self.tls:
            return None
        try:
            context = ssl.create_default_context(
                cafile=str(self.tls_ca_file) if self.tls_ca_file else None
            )
            if self.tls_cert_file is not None:
                key = str(self.tls_key_file) if self.tls_key_file else None
                context.load_cert_chain(str(self.tls_cert_file), key)
        except (ssl.SSLError, OSError, ValueError) as exc:
            files = [str(p) for p in (self.tls_ca_file, self.tls_cert_file, self.tls_key_file) if p]
            reason = getattr(exc, "reason", None) or getattr(exc, "strerror", None) or exc
            msg = f"mqtt TLS files {', '.join(files) or '(system CAs)'}: {reason}"
            raise ConfigError(msg) from None
        return context

    @property
    def host(self) -> str:
        return _split_broker(self.broker)[0]

    @property
    def port(self) -> int:
        return _split_broker(self.broker)[1]

    @property
    def tls(self) -> bool:
        return _split_broker(self.broker)[2]

    def topic(self, name: str) -> str:
        return f"{self.topic_prefix}/{self.device_id}/{name}"


def _split_broker(url: str) -> tuple[str, int, bool]:
    """(host, port, tls) of ``mqtt://host[:port]`` or ``mqtts://host[:port]``, else ValueError.

    Nothing is guessed: a URL without a scheme, port 0 or an empty host is refused
    (``garbage`` would otherwise be a host name retried forever).
    """
    url_shown = shown(url, 80)
    if "://" not in url:
        msg = f"broker {url_shown}: give a URL, mqtt://host[:port] or mqtts://host[:port]"
        raise ValueError(msg)
    try:
        parts = urlsplit(url)
    except ValueError as exc:
        msg = f"broker {url_shown}: {exc}"
        raise ValueError(msg) from None
    if parts.scheme not in ("mqtt", "mqtts"):
        msg = f"broker {url_shown}: scheme must be mqtt:// or mqtts://"
        raise ValueError(msg)
    if parts.username or parts.password:
        msg = "broker URL must not carry credentials; use mqtt.username and SCOTTI_MQTT_PASSWORD"
        raise ValueError(msg)
    try:
        port = parts.port
    except ValueError:
        port = -1
    if port is not None and not 1 <= port <= 65535:
        msg = f"broker {url_shown}: port must be 1..65535"
        raise ValueError(msg)
    if not parts.hostname:
        msg = f"broker {url_shown}: no host"
        raise ValueError(msg)
    if parts.path not in ("", "/") or parts.query or parts.fragment:
        msg = f"broker {url_shown}: only mqtt://host[:port], no path or query"
        raise ValueError(msg)
    tls = parts.scheme == "mqtts"
    return parts.hostname, port if port is not None else (8883 if tls else 1883), tls
