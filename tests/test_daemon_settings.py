"""Settings: precedence CLI > env > file > defaults, one-line errors, the secret stays secret."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import BaseModel
from scotti.daemon.input.speed import parse_speed
from scotti.daemon.settings import ConfigError, load_settings, sanitise_device_id

from tests.support.sessions import write_synthetic_session

PORT = {"source": {"port": "/dev/ttyACM0"}}


@pytest.fixture(autouse=True)
def clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    for key in list(os.environ):
        if key.startswith("SCOTTI_"):
            monkeypatch.delenv(key)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "scotti-daemon.toml"
    path.write_text(text)
    return path


def test_defaults() -> None:
    s = load_settings(PORT)
    assert s.mqtt.host == "localhost"
    assert s.mqtt.port == 1883
    assert s.mqtt.topic_prefix == "scotti"
    assert s.mqtt.format == "json"
    assert s.mqtt.device_id
    assert s.source.kind == "port"
    assert s.mqtt.topic("pose") == f"scotti/{s.mqtt.device_id}/pose"


def test_precedence_cli_over_env_over_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = write(
        tmp_path,
        '[source]\nport = "/dev/file"\n[mqtt]\nbroker = "mqtt://file:1"\n'
        'topic_prefix = "fromfile"\ndevice_id = "filedev"\n[model]\nthreads = 3\n',
    )
    monkeypatch.setenv("SCOTTI_MQTT_BROKER", "mqtt://env:2")
    monkeypatch.setenv("SCOTTI_MQTT_DEVICE_ID", "envdev")
    monkeypatch.setenv("SCOTTI_LOG_LEVEL", "DEBUG")
    s = load_settings({"mqtt": {"device_id": "clidev"}}, cfg)
    assert s.mqtt.device_id == "clidev"  # CLI
    assert (s.mqtt.host, s.mqtt.port) == ("env", 2)  # env over file
    assert s.mqtt.topic_prefix == "fromfile"  # file over default
    assert s.model.threads == 3
    assert s.source.port == "/dev/file"
    assert s.log_level == "debug"


def test_source_on_cli_replaces_the_file_source(tmp_path: Path) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=1).path
    cfg = write(tmp_path, '[source]\nport = "/dev/file"\n')
    s = load_settings({"source": {"replay": session, "speed": parse_speed("max")}}, cfg)
    assert s.source.kind == "replay"
    assert s.source.port is None
    assert s.source.speed == "max"


@pytest.mark.parametrize(
    ("cli", "expected"),
    [
        ({"mqtt": {"broker": "mqtt://h:70000"}}, "mqtt.broker: broker 'mqtt://h:70000': port"),
        ({"mqtt": {"device_id": "a/b"}}, "mqtt.device_id: device id 'a/b' must not contain"),
        ({"mqtt": {"device_id": "x+"}}, "mqtt.device_id"),
        ({"mqtt": {"device_id": ""}}, "mqtt.device_id: device id must not be empty"),
        ({"mqtt": {"topic_prefix": "a/#"}}, "mqtt.topic_prefix"),
        ({"mqtt": {"format": "xml"}}, "mqtt.format: Input should be 'json' or 'msgpack'"),
        ({"model": {"threads": 0}}, "model.threads: Input should be greater than or equal to 1"),
        ({"mqtt": {"broker": "http://h"}}, "mqtt.broker: broker 'http://h': scheme must be"),
        ({"mqtt": {"broker": "mqtt://h:0"}}, "mqtt.broker: broker 'mqtt://h:0': port must be"),
        ({"mqtt": {"broker": "garbage"}}, "mqtt.broker: broker 'garbage': give a URL"),
        ({"mqtt": {"broker": "h:1883"}}, "mqtt.broker: broker 'h:1883': give a URL"),
        ({"mqtt": {"broker": "mqtt://:1883"}}, "mqtt.broker: broker 'mqtt://:1883': no host"),
        ({"mqtt": {"broker": "mqtt://"}}, "mqtt.broker: broker 'mqtt://': no host"),
        ({"mqtt": {"broker": "mqtt://h/x"}}, "mqtt.broker: broker 'mqtt://h/x': only mqtt://"),
        ({"mqtt": {"device_id": "d" * 65}}, "mqtt.device_id: device id 'dddd"),
        ({"mqtt": {"device_id": "caf\u00e9"}}, "mqtt.device_id: device id 'caf\u00e9': at most 64"),
        ({"mqtt": {"topic_prefix": "p" * 129}}, "mqtt.topic_prefix: topic prefix 'pppp"),
        ({"source": {"port": None, "replay": "r" * 5000}}, "source: replay file not found"),
        (
            {"mqtt": {"broker": "mqtt://h", "tls_ca_file": "/etc/hostname"}},
            "mqtt: tls_ca_file given but the broker URL is not mqtts://",
        ),
        (
            {"mqtt": {"broker": "mqtts://h", "tls_key_file": "/etc/hostname"}},
            "mqtt: tls_key_file given without tls_cert_file",
        ),
        (
            {"mqtt": {"broker": "mqtts://h", "tls_ca_file": "/no/such/ca.pem"}},
            "mqtt: tls_ca_file: file not found: '/no/such/ca.pem'",
        ),
    ],
)
def test_bad_setting_names_itself_in_one_line(
    cli: dict[str, dict[str, object]], expected: str
) -> None:
    merged = {**PORT, **cli}
    with pytest.raises(ConfigError) as info:
        load_settings(merged)
    assert str(info.value).startswith(expected)
    assert "\n" not in str(info.value)


def test_no_source_and_two_sources() -> None:
    with pytest.raises(ConfigError, match=r"^source: no source"):
        load_settings({})
    with pytest.raises(ConfigError, match="only one source"):
        load_settings({"source": {"port": "/dev/x", "simulate": "demo"}})


def test_bad_env_value_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SCOTTI_MQTT_KEEPALIVE_S", "many")
    with pytest.raises(ConfigError, match=r"^mqtt.keepalive_s: Input should be a valid integer"):
        load_settings(PORT)


def test_bad_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_settings(PORT, tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match=r"config file .*: Expected"):
        load_settings(PORT, write(tmp_path, "[mqtt\n"))
    with pytest.raises(
        ConfigError, match=r"^mqtt.brokr: unknown setting; did you mean mqtt.broker"
    ):
        load_settings(PORT, write(tmp_path, '[mqtt]\nbrokr = "x"\n'))


def test_password_from_env_or_file_never_from_config(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(ConfigError, match=r"^mqtt\.password: not allowed in the config file"):
        load_settings(PORT, write(tmp_path, '[mqtt]\npassword = "hunter2"\n'))
    pw = tmp_path / "pw"
    pw.write_text("s3cret-from-file\n")
    s = load_settings({**PORT, "mqtt": {"password_file": pw}})
    assert s.mqtt.password is not None
    assert s.mqtt.password.get_secret_value() == "s3cret-from-file"
    monkeypatch.setenv("SCOTTI_MQTT_PASSWORD", "s3cret-from-env")
    s = load_settings(PORT)
    assert s.mqtt.password is not None
    assert s.mqtt.password.get_secret_value() == "s3cret-from-env"
    assert "s3cret" not in repr(s)
    assert "s3cret" not in str(s.summary())
    assert s.summary()["mqtt"]["password_set"] is True


def test_device_id_from_host_name_is_sanitised() -> None:
    assert sanitise_device_id("Pi@Lab 2.local") == "pi-lab-2"
    assert sanitise_device_id("+++") == "scotti"


def test_missing_replay_file_and_missing_model(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="replay file not found"):
        load_settings({"source": {"replay": tmp_path / "nope"}})
    s = load_settings({**PORT, "model": {"path": tmp_path / "nope.onnx"}})
    with pytest.raises(ConfigError, match=r"^model.path: file not found"):
        s.model.resolved_path()


def test_example_config_loads_and_shows_every_setting() -> None:
    from scotti.daemon.settings import (
        DeviceSettings,
        InferenceSettings,
        ModelSettings,
        MqttSettings,
        Settings,
        SourceSettings,
    )
    from scotti.daemon.settings.outputs import OutputSettings

    example = Path(__file__).parent.parent / "systemd" / "scotti-daemon.toml"
    s = load_settings({}, example)
    assert s.source is not None
    assert s.source.port == "/dev/scotti-receiver"
    text = example.read_text()
    sections: dict[str, type[BaseModel]] = {
        "": Settings,
        "source": SourceSettings,
        "model": ModelSettings,
        "mqtt": MqttSettings,
        "outputs": OutputSettings,
        "inference": InferenceSettings,
        "devices": DeviceSettings,  # a commented [[devices]] example
    }
    for section, model in sections.items():
        for name in model.model_fields:
            if name in sections or name in ("password", "token"):  # secrets: never in the file
                continue
            assert f"\n{name} = " in text or f"\n# {name} = " in text, f"{section}.{name}"


def test_a_long_value_is_cut_in_the_message() -> None:
    with pytest.raises(ConfigError) as info:
        load_settings({**PORT, "mqtt": {"device_id": "d" * 10_000}})
    assert len(str(info.value)) < 200  # not a 10 kB line (nor a 10 kB topic)
    assert "(10000 chars)" in str(info.value)


def test_device_id_limits_and_sanitised_host_names() -> None:
    assert load_settings({**PORT, "mqtt": {"device_id": "d" * 64}}).mqtt.device_id == "d" * 64
    assert load_settings({**PORT, "mqtt": {"device_id": "lab-1_a.b"}}).mqtt.device_id
    assert len(sanitise_device_id("h" * 300)) == 64


def test_broker_url_parts() -> None:
    mqtt = load_settings({**PORT, "mqtt": {"broker": "mqtts://broker.lan"}}).mqtt
    assert (mqtt.host, mqtt.port, mqtt.tls) == ("broker.lan", 8883, True)
    mqtt = load_settings({**PORT, "mqtt": {"broker": "mqtt://[::1]:1884"}}).mqtt
    assert (mqtt.host, mqtt.port, mqtt.tls) == ("::1", 1884, False)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('[mqtt]\nbrokr = "mqtt://x"\n', "mqtt.brokr: unknown setting; did you mean mqtt.broker?"),
        ('log_levl = "info"\n', "log_levl: unknown setting; did you mean log_level?"),
        ("[outputs]\nrecord_mcp = 'x.mcap'\n", "did you mean outputs.record_mcap?"),
        ("[mqtt]\nzzz = 1\n", "mqtt.zzz: unknown setting"),
    ],
)
def test_a_misspelt_key_gets_a_did_you_mean(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_settings(PORT, write(tmp_path, text))
    assert message in str(info.value)
    if "zzz" in text:
        assert "did you mean" not in str(info.value)  # nothing close: no guess


DEVICES = '[[devices]]\nid = "lab1"\nport = "/dev/serial/by-id/usb-A"\n[[devices]]\nid = "lab2"\n'


def test_a_devices_table_gives_one_device_each_with_its_own_topics(tmp_path: Path) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=1).path
    cfg = write(tmp_path, DEVICES + f'replay = "{session}"\nspeed = "max"\n')
    s = load_settings({}, cfg)
    assert s.source is None
    assert [(d.id, d.kind) for d in s.device_list()] == [("lab1", "port"), ("lab2", "replay")]
    lab1, lab2 = s.device_list()
    assert lab1.port == "/dev/serial/by-id/usb-A"
    assert lab2.speed == "max"
    assert s.mqtt_for(lab2).topic("pose") == "scotti/lab2/pose"
    assert s.mqtt_for(lab1).device_id == "lab1"
    assert s.inference.batch  # batched unless asked otherwise


def test_the_one_pair_shorthand_is_a_device_named_by_device_id() -> None:
    s = load_settings({**PORT, "mqtt": {"device_id": "wearer"}})
    (only,) = s.device_list()
    assert (only.id, only.port) == ("wearer", "/dev/ttyACM0")
    assert s.mqtt_for(only) is s.mqtt  # its client id and topics exactly as before


def test_a_port_on_the_command_line_replaces_the_files_devices(tmp_path: Path) -> None:
    cfg = write(tmp_path, DEVICES + 'port = "/dev/serial/by-id/usb-B"\n')
    s = load_settings({"source": {"port": "/dev/ttyUSB9"}, "mqtt": {"device_id": "x"}}, cfg)
    assert [(d.id, d.port) for d in s.device_list()] == [("x", "/dev/ttyUSB9")]


def test_speed_alone_applies_to_devices_that_set_none(tmp_path: Path) -> None:
    cfg = write(tmp_path, DEVICES + 'simulate = "demo"\nspeed = 2\n')
    s = load_settings({"source": {"speed": "max"}}, cfg)
    assert [d.speed for d in s.device_list()] == ["max", 2.0]


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        (DEVICES + 'port = "/dev/b"\n[[devices]]\nid = "lab1"\nport = "/dev/c"\n', "given twice"),
        ('[[devices]]\nid = "a/b"\nport = "/dev/a"\n', "must not contain '/'"),
        ('[[devices]]\nid = "a+"\nport = "/dev/a"\n', "holds the wildcard '+'"),
        ('[[devices]]\nid = ""\nport = "/dev/a"\n', "must not be empty"),
        ('[[devices]]\nid = "a"\n', "give exactly one of port, replay, simulate (got none)"),
        ('[[devices]]\nid = "a"\nport = "/dev/a"\nsimulate = "demo"\n', "port and simulate"),
        ('[[devices]]\nid = "a"\nreplay = "/no/such.scotti"\n', "replay file not found"),
        ('[[devices]]\nid = "a"\nprot = "/dev/a"\n', "unknown setting"),
        ('[[devices]]\nport = "/dev/a"\n', "devices.0.id: Field required"),
        ('[source]\nport = "/dev/x"\n' + DEVICES + 'port = "/dev/b"\n', "not both"),
    ],
)
def test_a_bad_devices_table_is_one_line(tmp_path: Path, toml: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_settings({}, write(tmp_path, toml))
    text = str(info.value)
    assert message in text
    assert "\n" not in text


def test_several_devices_take_the_outputs(tmp_path: Path) -> None:
    # MCAP, Foxglove, LSL and web serve every device (channels, outlets, pages per device).
    toml = DEVICES + 'port = "/dev/b"\n[outputs]\nlsl = true\nweb = 8080\nfoxglove = 8765\n'
    s = load_settings({}, write(tmp_path, toml))
    assert len(s.device_list()) == 2
    assert s.outputs.lsl
    assert s.outputs.web == 8080
    assert s.outputs.foxglove == 8765


def test_several_devices_record_into_a_directory(tmp_path: Path) -> None:
    toml = DEVICES + 'port = "/dev/b"\n'
    with pytest.raises(ConfigError, match="record: with several devices give a directory"):
        load_settings({"record": tmp_path / "one.scotti"}, write(tmp_path, toml))
    s = load_settings({"record": tmp_path}, write(tmp_path, toml))
    assert s.record == tmp_path
