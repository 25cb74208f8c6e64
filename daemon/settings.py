"""The daemon's configuration: one validated model, loaded once at start.

Every setting can come from four places; the first that sets it wins:
command line > ``SCOTTI_*`` environment > TOML file (``--config``) > default.
Environment names are ``SCOTTI_<SECTION>_<FIELD>`` (``SCOTTI_MQTT_BROKER``,
``SCOTTI_MQTT_PASSWORD``, ``SCOTTI_MODEL_THREADS``) or ``SCOTTI_<FIELD>`` for
top-level fields (``SCOTTI_LOG_LEVEL``).

The broker connection may use TLS (``mqtts://``) with the system's CAs or
``mqtt.tls_ca_file``, and a client certificate (``tls_cert_file`` +
``tls_key_file``); the files are read at start, so a missing or broken one is a
one-line error then, not a reconnect loop later.

The broker password is a secret: it comes from ``SCOTTI_MQTT_PASSWORD`` or
``mqtt.password_file``, never from the TOML file, and is held as a
``SecretStr`` so that neither logs nor the retained ``info`` message show it.
"""

from __future__ import annotations

import difflib
import re
import socket
import ssl
import tomllib
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, ClassVar, Final, Literal
from urllib.parse import urlsplit

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SecretStr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)
from scotti.daemon.errors import DaemonError
from scotti.daemon.outputs.settings import OutputSettings
from scotti.daemon.speed import Speed, parse_speed

EX_CONFIG: Final = 78  # sysexits.h: configuration error
DEFAULT_MODEL_NAME: Final = "scotti-default.onnx"  # preferred among the shipped step graphs
_TOPIC_FORBIDDEN: Final = re.compile(r"[+#/\x00-\x1f\s]")
DEVICE_ID_MAX: Final = 64  # characters; a topic level, a client id, a file name
_DEVICE_ID: Final = re.compile(r"[A-Za-z0-9_.-]+")  # safe in topics, client ids and file names
TOPIC_PREFIX_MAX: Final = 128  # characters, all levels together


class ConfigError(DaemonError):
    """A setting that cannot be used; the message is one line naming it."""


def sanitise_device_id(name: str) -> str:
    """A host name made safe for one MQTT topic level (``pi@lab 2`` -> ``pi-lab-2``)."""
    cleaned = re.sub(r"[^A-Za-z0-9_.-]+", "-", name.split(".")[0]).strip("-").lower()
    return cleaned[:DEVICE_ID_MAX].strip("-") or "scotti"


def _is_file(path: Path) -> bool:
    """``path.is_file()``, False (not an exception) for a name the OS cannot even look up."""
    try:
        return path.is_file()
    except (OSError, ValueError):  # ENAMETOOLONG, ELOOP, an embedded NUL
        return False


def _shown(value: str, limit: int = 40) -> str:
    """``value`` for an error message: repr, cut to ``limit`` characters."""
    return repr(value) if len(value) <= limit else repr(value[:limit]) + f"... ({len(value)} chars)"


def _check_topic_level(value: str, what: str) -> str:
    if not value:
        msg = f"{what} must not be empty"
        raise ValueError(msg)
    if _TOPIC_FORBIDDEN.search(value):
        msg = f"{what} {_shown(value)} must not contain '+', '#', '/', spaces or control characters"
        raise ValueError(msg)
    return value


def check_device_id(v: str) -> str:
    """A device id usable as one MQTT topic level, a client id and a file name."""
    _check_topic_level(v, "device id")
    if len(v) > DEVICE_ID_MAX or not _DEVICE_ID.fullmatch(v):
        msg = f"device id {_shown(v)}: at most {DEVICE_ID_MAX} characters of A-Z a-z 0-9 _ . -"
        raise ValueError(msg)
    return v


class SourceSettings(BaseModel):
    """Where the bytes come from: exactly one of port, replay, simulate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    port: str | None = None  # serial device, e.g. /dev/scotti-receiver
    replay: Path | None = None  # session file fed back through the live path
    simulate: str | None = None  # scene name (sim/scenes/NAME.toml) or a scene TOML path
    speed: Speed = 1.0  # replay / simulate rate: 1 = real time, N times, or max

    @field_validator("speed", mode="before")
    @classmethod
    def _speed(cls, v: object) -> Speed:
        return parse_speed(v)

    @model_validator(mode="after")
    def _exactly_one(self) -> SourceSettings:
        given = [n for n in ("port", "replay", "simulate") if getattr(self, n) is not None]
        if not given:
            msg = "no source: set --port (source.port), --replay, --simulate or [[devices]]"
            raise ValueError(msg)
        if len(given) > 1:
            msg = f"give only one source, got {' and '.join(given)}"
            raise ValueError(msg)
        if self.replay is not None and not _is_file(self.replay):
            msg = f"replay file not found: {self.replay}"
            raise ValueError(msg)
        return self

    @property
    def kind(self) -> Literal["port", "replay", "simulate"]:
        return "port" if self.port else "replay" if self.replay else "simulate"


class DeviceSettings(SourceSettings):
    """One insole pair in ``[[devices]]``: its id (the topic level) and its source.

    A receiver is best named by its ``/dev/serial/by-id/...`` path: it stays the
    same across reboots and replugging, whichever USB port it is in.
    """

    id: str  # scotti/<id>/...: unique in the daemon, a valid MQTT topic level
    record: Path | None = None  # this device's recording (default: the top-level record)

    @field_validator("id")
    @classmethod
    def _id(cls, v: str) -> str:
        return check_device_id(v)

    @model_validator(mode="after")
    def _exactly_one(self) -> DeviceSettings:
        given = [n for n in ("port", "replay", "simulate") if getattr(self, n) is not None]
        if len(given) != 1:
            what = f"got {' and '.join(given)}" if given else "got none"
            msg = f"device {self.id!r}: give exactly one of port, replay, simulate ({what})"
            raise ValueError(msg)
        if self.replay is not None and not _is_file(self.replay):
            msg = f"device {self.id!r}: replay file not found: {self.replay}"
            raise ValueError(msg)
        return self


class InferenceSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    # One model call for every device with a frame ready (the step graph's batch axis);
    # false: one call per device, the same thread (kept to measure the difference).
    batch: bool = True
    # More ready frames than this go in several calls (the step's cost per frame is
    # lowest at a few frames per call: python -m scotti.daemon.tools.bench --step-batches).
    max_batch: Annotated[int, Field(ge=1, le=1024)] = 8
    queue_size: Annotated[int, Field(ge=1, le=256)] = 16  # frames per device waiting


class ModelSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    path: Path | None = None  # None: the model shipped in the installed package
    threads: Annotated[int, Field(ge=1, le=64)] = 1  # onnxruntime intra-op threads

    def resolved_path(self) -> Path:
        """The model file to load; the shipped default when ``path`` is unset."""
        if self.path is not None:
            if not _is_file(self.path):
                msg = f"model.path: file not found: {self.path}"
                raise ConfigError(msg)
            return self.path
        return default_model_path()


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
    pressure: bool = False  # also publish downsampled pressure frames (the demo's view)
    pressure_downsample: Annotated[int, Field(ge=1, le=8)] = 2
    tls_ca_file: Path | None = None  # CA bundle (PEM) the broker's certificate must chain to
    tls_cert_file: Path | None = None  # client certificate (PEM), for brokers that want one
    tls_key_file: Path | None = None  # its private key (PEM); default: inside tls_cert_file

    @field_validator("device_id")
    @classmethod
    def _device_id(cls, v: str) -> str:
        return check_device_id(v)

    @field_validator("topic_prefix")
    @classmethod
    def _prefix(cls, v: str) -> str:
        # A prefix may have several levels ("site/a"), none of them empty or a wildcard.
        if len(v) > TOPIC_PREFIX_MAX:
            msg = f"topic prefix {_shown(v)}: at most {TOPIC_PREFIX_MAX} characters"
            raise ValueError(msg)
        for level in v.split("/"):
            if not level or _TOPIC_FORBIDDEN.search(level):
                msg = f"topic prefix {_shown(v)}: levels must be non-empty, without + # or spaces"
                raise ValueError(msg)
        return v

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
            if not _is_file(path):
                msg = f"{name}: file not found: {_shown(str(path), 200)}"
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
    shown = _shown(url, 80)
    if "://" not in url:
        msg = f"broker {shown}: give a URL, mqtt://host[:port] or mqtts://host[:port]"
        raise ValueError(msg)
    try:
        parts = urlsplit(url)
    except ValueError as exc:
        msg = f"broker {shown}: {exc}"
        raise ValueError(msg) from None
    if parts.scheme not in ("mqtt", "mqtts"):
        msg = f"broker {shown}: scheme must be mqtt:// or mqtts://"
        raise ValueError(msg)
    if parts.username or parts.password:
        msg = "broker URL must not carry credentials; use mqtt.username and SCOTTI_MQTT_PASSWORD"
        raise ValueError(msg)
    try:
        port = parts.port
    except ValueError:
        port = -1
    if port is not None and not 1 <= port <= 65535:
        msg = f"broker {shown}: port must be 1..65535"
        raise ValueError(msg)
    if not parts.hostname:
        msg = f"broker {shown}: no host"
        raise ValueError(msg)
    if parts.path not in ("", "/") or parts.query or parts.fragment:
        msg = f"broker {shown}: only mqtt://host[:port], no path or query"
        raise ValueError(msg)
    tls = parts.scheme == "mqtts"
    return parts.hostname, port if port is not None else (8883 if tls else 1883), tls


class Settings(BaseSettings):
    """Everything the daemon reads at start. Sections mirror the TOML file."""

    model_config = SettingsConfigDict(
        env_prefix="SCOTTI_",
        env_nested_delimiter="_",
        env_nested_max_split=1,
        extra="forbid",
        frozen=True,
    )

    config_file: ClassVar[Path | None] = None  # set on a subclass by load_settings

    # One pair: [source] (or --port/--replay/--simulate, --device-id); several: [[devices]].
    source: SourceSettings | None = None
    devices: tuple[DeviceSettings, ...] = ()
    inference: InferenceSettings = InferenceSettings()
    model: ModelSettings = ModelSettings()
    mqtt: MqttSettings = MqttSettings()
    record: Path | None = None  # append the raw byte stream to this session file
    outputs: OutputSettings = OutputSettings()  # MCAP, Foxglove, LSL, web (daemon/outputs/)
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    stop_timeout_s: Annotated[float, Field(gt=0, le=120)] = 5.0

    @field_validator("log_level", mode="before")
    @classmethod
    def _lower(cls, v: object) -> object:
        return v.lower() if isinstance(v, str) else v

    @model_validator(mode="before")
    @classmethod
    def _source_or_devices(cls, data: Any) -> Any:
        """``[source]`` or ``[[devices]]``: a lone ``speed`` (``--speed max``) is not a source
        and becomes the speed of every device that sets none."""
        if not isinstance(data, dict):
            return data
        if not data.get("devices"):  # so a missing source reads "no source", not "None"
            return {**data, "source": data.get("source") or {}}
        source = data.get("source") or {}
        if not isinstance(source, dict):
            return data
        given = [k for k in ("port", "replay", "simulate") if source.get(k) is not None]
        if given:
            msg = f"give either [source] ({given[0]}) or [[devices]], not both"
            raise ValueError(msg)
        speed = source.get("speed")
        devices = data["devices"]
        if speed is not None and isinstance(devices, list | tuple):
            devices = [{"speed": speed, **d} if isinstance(d, dict) else d for d in devices]
        return {**{k: v for k, v in data.items() if k != "source"}, "devices": devices}

    @model_validator(mode="after")
    def _devices(self) -> Settings:
        if self.source is None and not self.devices:
            msg = "no source: set --port (source.port), --replay, --simulate or [[devices]]"
            raise ValueError(msg)
        ids = [d.id for d in self.devices]
        twice = sorted({i for i in ids if ids.count(i) > 1})
        if twice:
            msg = f"devices: id {twice[0]!r} given twice; each device needs its own id"
            raise ValueError(msg)
        if len(self.devices) > 1:
            unnamed = [d.id for d in self.devices if d.record is None]
            if self.record is not None and unnamed and not self.record.is_dir():
                msg = f"record: with several devices give a directory, {self.record} is not one"
                raise ValueError(msg)
        return self

    def device_list(self) -> tuple[DeviceSettings, ...]:
        """Every device the daemon serves; ``[source]`` is the one-pair shorthand, its id
        ``mqtt.device_id``."""
        if self.devices:
            return self.devices
        assert self.source is not None
        return (
            DeviceSettings(
                id=self.mqtt.device_id,
                port=self.source.port,
                replay=self.source.replay,
                simulate=self.source.simulate,
                speed=self.source.speed,
            ),
        )

    def mqtt_for(self, device: DeviceSettings) -> MqttSettings:
        """The MQTT settings of one device: its topics and its own client (own last will)."""
        if device.id == self.mqtt.device_id and len(self.device_list()) == 1:
            return self.mqtt
        client_id = f"{self.mqtt.client_id}-{device.id}" if self.mqtt.client_id else None
        return self.mqtt.model_copy(update={"device_id": device.id, "client_id": client_id})

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        return (init_settings, env_settings, _TomlSource(settings_cls))

    def summary(self) -> dict[str, Any]:
        """Settings as published in ``info``: paths and choices, never the secret."""
        data = self.model_dump(mode="json", exclude={"mqtt": {"password", "password_file"}})
        data["mqtt"]["password_set"] = self.mqtt.password is not None
        return data


class _TomlSource(PydanticBaseSettingsSource):
    """The ``--config`` file; its path travels in the settings class's ``config_file``."""

    def get_field_value(self, field: Any, field_name: str) -> tuple[Any, str, bool]:
        return None, field_name, False  # unused: __call__ returns the whole file

    def __call__(self) -> dict[str, Any]:
        path = getattr(self.settings_cls, "config_file", None)
        if path is None:
            return {}
        try:
            with Path(path).open("rb") as f:
                data = tomllib.load(f)
        except OSError as exc:
            msg = f"cannot read config file {path}: {exc.strerror}"
            raise ConfigError(msg) from None
        except tomllib.TOMLDecodeError as exc:
            msg = f"config file {path}: {exc}"
            raise ConfigError(msg) from None
        if "password" in data.get("mqtt", {}):
            msg = "mqtt.password: not allowed in the config file; use SCOTTI_MQTT_PASSWORD"
            raise ConfigError(msg + " or mqtt.password_file")
        return data


def load_settings(cli: dict[str, Any], config_file: Path | None = None) -> Settings:
    """Merge command line (nested dict, unset keys absent), env, file and defaults.

    Raises ``ConfigError`` with one line naming the bad setting.
    """
    cli = {k: dict(v) if isinstance(v, dict) else v for k, v in cli.items()}
    if any(k in cli.get("source", {}) for k in ("port", "replay", "simulate")):
        # A source given on the command line replaces the one from env or file.
        for k in ("port", "replay", "simulate"):
            cli["source"].setdefault(k, None)
    if cli.get("source", {}).keys() & {"port", "replay", "simulate"}:
        cli["devices"] = ()  # the one-pair shorthand on the command line wins over a file's
    cls: type[Settings] = Settings
    if config_file is not None:
        cls = type("Settings", (Settings,), {"config_file": config_file})
    try:
        return cls(**cli)
    except ValidationError as exc:
        raise ConfigError(_one_line(exc)) from None


def _one_line(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors(include_url=False):
        loc = ".".join(str(p) for p in err["loc"])
        message = str(err["msg"]).removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            message = "unknown setting" + _did_you_mean(err["loc"])
        parts.append(f"{loc}: {message}" if loc else message)
    return "; ".join(parts)


def _did_you_mean(loc: tuple[int | str, ...]) -> str:
    """``; did you mean mqtt.broker?`` for a misspelt key, as git and cargo say it."""
    model: type[BaseModel] = Settings
    for part in loc[:-1]:
        field = model.model_fields.get(str(part))
        annotation = field.annotation if field is not None else None
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return ""
        model = annotation
    close = difflib.get_close_matches(str(loc[-1]), list(model.model_fields), n=1, cutoff=0.6)
    return f"; did you mean {'.'.join([*map(str, loc[:-1]), close[0]])}?" if close else ""


def default_model_path() -> Path:
    """The step graph shipped in the installed package's ``models/`` folder."""
    folder = Path(str(resources.files("scotti.models")))
    steps = sorted(
        p
        for p in folder.glob("*.onnx")
        if not p.name.endswith(".window.onnx") and ".int8." not in p.name
    )
    preferred = folder / DEFAULT_MODEL_NAME
    if preferred in steps:
        return preferred
    if len(steps) == 1:
        return steps[0]
    if not steps:
        msg = f"model: no model shipped in {folder}; pass --model PATH.onnx"
    else:
        names = ", ".join(p.name for p in steps)
        msg = f"model: several models in {folder} ({names}); pass --model PATH.onnx"
    raise ConfigError(msg)
