"""The daemon's configuration: one validated model, loaded once at start.

Every setting can come from four places; the first that sets it wins:
command line > ``SCOTTI_*`` environment > TOML file (``--config``) > default.
Environment names are ``SCOTTI_<SECTION>_<FIELD>`` (``SCOTTI_MQTT_BROKER``,
``SCOTTI_MQTT_PASSWORD``, ``SCOTTI_MODEL_THREADS``) or ``SCOTTI_<FIELD>`` for
top-level fields (``SCOTTI_LOG_LEVEL``).

This module holds the top-level ``Settings``, the small ``[inference]`` and
``[model]`` sections and the loader. The larger sections live in their own
modules: ``[source]`` / ``[[devices]]`` in ``source_settings``, ``[mqtt]``
in ``mqtt_settings`` (TLS, the broker password), ``[outputs]`` in
``outputs.settings``; the checks they share and ``ConfigError`` in
``config_checks``. Their public names are re-exported here, so
``from scotti.daemon.settings import MqttSettings, ConfigError`` keeps working.
"""

from __future__ import annotations

import difflib
import tomllib
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, ClassVar, Final, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)
from scotti.daemon.settings.checks import (
    DEVICE_ID_MAX,
    EX_CONFIG,
    TOPIC_PREFIX_MAX,
    ConfigError,
    check_device_id,
    is_file,
    sanitise_device_id,
)
from scotti.daemon.settings.mqtt import MqttSettings
from scotti.daemon.settings.outputs import OutputSettings
from scotti.daemon.settings.source import DeviceSettings, SourceSettings

__all__ = [
    "DEFAULT_MODEL_NAME",
    "DEVICE_ID_MAX",
    "EX_CONFIG",
    "TOPIC_PREFIX_MAX",
    "ConfigError",
    "DeviceSettings",
    "InferenceSettings",
    "ModelSettings",
    "MqttSettings",
    "Settings",
    "SourceSettings",
    "check_device_id",
    "default_model_path",
    "load_settings",
    "sanitise_device_id",
]

DEFAULT_MODEL_NAME: Final = "scotti-default.onnx"  # preferred among the shipped step graphs


class InferenceSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    # One model call for every device with a frame ready (the step graph's batch axis);
    # false: one call per device, the same thread (kept to measure the difference).
    batch: bool = True
    # More ready frames than this go in several calls (the step's cost per frame is
    # lowest at a few frames per call: python -m scotti.daemon.tools.bench --step-batches).
    max_batch: Annotated[int, Field(ge=1, le=1024)] = 8
    # Wait up to this long for the frames of other devices that are due, to run them in
    # one call (fewer, fuller calls: less CPU per pair; docs/performance.md); 0: run what
    # is ready at once. One pair never waits: no other device is due.
    gather_ms: Annotated[float, Field(ge=0, le=50)] = 4.0
    queue_size: Annotated[int, Field(ge=1, le=256)] = 16  # frames per device waiting


class ModelSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    path: Path | None = None  # None: the model shipped in the installed package
    threads: Annotated[int, Field(ge=1, le=64)] = 1  # onnxruntime intra-op threads

    def resolved_path(self) -> Path:
        """The model file to load; the shipped default when ``path`` is unset."""
        if self.path is not None:
            if not is_file(self.path):
                msg = f"model.path: file not found: {self.path}"
                raise ConfigError(msg)
            return self.path
        return default_model_path()


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
    # Worker processes the devices are shared among (daemon/service/processes.py): each its own
    # event loop and model. 1: every device in this process.
    processes: Annotated[int, Field(ge=1, le=64)] = 1
    stop_timeout_s: Annotated[float, Field(gt=0, le=120)] = 5.0

    @field_validator("log_level", mode="before")
    @classmethod
    def _lower(cls, v: object) -> object:
        return v.lower() if isinstance(v, str) else v

    @model_validator(mode="before")
    @classmethod
    def _source_or_devices(cls, data: Any) -> Any:
        """``[source]`` or ``[[devices]]``: a lone ``speed`` (``--speed max``) or ``once``
        is not a source and becomes that of every device that sets none."""
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
        shared = {k: source[k] for k in ("speed", "once") if source.get(k) is not None}
        devices = data["devices"]
        if shared and isinstance(devices, list | tuple):
            devices = [{**shared, **d} if isinstance(d, dict) else d for d in devices]
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
        if self.processes > 1 and self.outputs.any:
            msg = (
                "processes: the outputs (web, foxglove, record_mcap, lsl) serve every device "
                "of one process; set processes = 1 to use them"
            )
            raise ValueError(msg)
        if len(self.devices) > 1:
            unnamed = [d.id for d in self.devices if d.record is None]
            shared = self.record is not None and "{device}" not in self.record.name
            if shared and unnamed and self.record is not None and not self.record.is_dir():
                msg = (
                    f"record: with several devices give a directory or a name with {{device}}, "
                    f"{self.record} is neither"
                )
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
                once=self.source.once,
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
        except UnicodeDecodeError as exc:  # TOML is UTF-8; tomllib lets this one through
            msg = (
                f"config file {path}: not UTF-8 (byte 0x{exc.object[exc.start]:02x} at {exc.start})"
            )
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
