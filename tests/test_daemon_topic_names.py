"""Topic prefix, device id, client id: what a broker would refuse or drop stops the
daemon at start (exit 78, one line naming the setting), what passes reaches a broker.

The refusals run the real ``scotti-daemon`` command: arguments (raw bytes where the
case is bytes that are not UTF-8), the environment and the config file. The port given
is never opened: the settings are checked before anything else.
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from pathlib import Path

import aiomqtt
import pytest
from scotti.daemon.mqtt.schemas import CONTROL_TOPICS, REQUESTS, TOPICS
from scotti.daemon.settings import ConfigError, MqttSettings, load_settings
from scotti.daemon.settings.checks import (
    DEVICE_ID_MAX,
    LONGEST_TOPIC_BYTES,
    TOPIC_BYTES_MAX,
    TOPIC_PREFIX_MAX,
    TOPIC_SUFFIX_MAX,
)
from scotti.daemon.tools.local_broker import Mosquitto

EXE = Path(sys.executable).with_name("scotti-daemon")
NEVER_OPENED = "/dev/scotti-test-never-opened"


def run_daemon(
    *args: str | bytes, env: dict[str, str | bytes] | None = None, timeout: float = 60
) -> subprocess.CompletedProcess[bytes]:
    base = {k: v for k, v in os.environb.items() if not k.startswith(b"SCOTTI_")}
    extra = {k.encode(): v if isinstance(v, bytes) else v.encode() for k, v in (env or {}).items()}
    return subprocess.run(
        [str(EXE), *args],
        capture_output=True,
        timeout=timeout,
        env={**base, **extra},
        check=False,
    )


def refused_line(result: subprocess.CompletedProcess[bytes]) -> str:
    """The one stderr line of a refusal at start; fails on anything else."""
    stderr = result.stderr.decode("utf-8", "replace")
    assert result.returncode == 78, (result.returncode, stderr)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert "Traceback" not in stderr
    assert lines[0].startswith("scotti-daemon: config error: "), lines[0]
    assert len(lines[0]) < 300, lines[0]  # a long value is cut, not echoed whole
    return lines[0]


@pytest.mark.parametrize(
    ("option", "value", "says"),
    [
        ("--topic-prefix", "$SYS", "a level starting with '$'"),
        ("--topic-prefix", "site/$share", "a level starting with '$'"),
        ("--topic-prefix", "a\x07b", "control character (U+0007"),
        ("--topic-prefix", "a\x1bb", "control character (U+001B"),
        ("--topic-prefix", "a\x7fb", "control character (U+007F"),
        ("--topic-prefix", "a\u0085b", "control character (U+0085"),
        ("--topic-prefix", "a\u009bb", "control character (U+009B"),
        ("--topic-prefix", b"sc\xffotti", "not valid UTF-8 (byte 0xff"),
        ("--topic-prefix", b"caf\xc3", "not valid UTF-8 (byte 0xc3"),
        ("--topic-prefix", b"x\xed\xa0\x80", "not valid UTF-8"),  # an encoded surrogate
        ("--topic-prefix", "a\ufffeb", "non-character (U+FFFE"),
        ("--topic-prefix", "a/+/b", "wildcard '+'"),
        ("--topic-prefix", "a/#", "wildcard '#'"),
        ("--topic-prefix", "a//b", "empty level"),
        ("--topic-prefix", "/a", "empty level"),
        ("--topic-prefix", "a/", "empty level"),
        ("--topic-prefix", "", "must not be empty"),
        ("--topic-prefix", "p" * 70_000, f"at most {TOPIC_PREFIX_MAX} characters"),
        ("--device-id", "$SYS", "starts with '$'"),
        ("--device-id", "lab\x1b[2J", "control character (U+001B"),
        ("--device-id", b"lab\xc3", "not valid UTF-8 (byte 0xc3"),
        ("--device-id", "a/b", "must not contain '/'"),
        ("--device-id", "a+", "wildcard '+'"),
    ],
)
def test_a_bad_name_on_the_command_line_stops_the_daemon_at_start(
    option: str, value: str | bytes, says: str
) -> None:
    result = run_daemon("--port", NEVER_OPENED, option, value)
    line = refused_line(result)
    key = {"--topic-prefix": "mqtt.topic_prefix", "--device-id": "mqtt.device_id"}[option]
    assert f": {key}: " in line, line
    assert says in line, line


@pytest.mark.parametrize(
    ("toml", "key", "says"),
    [
        ('[mqtt]\ntopic_prefix = "$SYS"\n', "mqtt.topic_prefix", "'$'"),
        ('[mqtt]\ntopic_prefix = "lab/\\u0000"\n', "mqtt.topic_prefix", "U+0000"),
        ('[mqtt]\ntopic_prefix = "lab\\u007f"\n', "mqtt.topic_prefix", "U+007F"),
        ('[mqtt]\ntopic_prefix = "lab/$x/y"\n', "mqtt.topic_prefix", "'$'"),
        ('[mqtt]\ndevice_id = "\\u009b"\n', "mqtt.device_id", "U+009B"),
        ('[mqtt]\ndevice_id = "$dev"\n', "mqtt.device_id", "'$'"),
        ('[mqtt]\nclient_id = "c\\u0000"\n', "mqtt.client_id", "U+0000"),
        ('[mqtt]\nusername = "u\\u001b"\n', "mqtt.username", "U+001B"),
        ('[[devices]]\nid = "$SYS"\nport = "/dev/x"\n', "devices.0.id", "'$'"),
        (
            '[[devices]]\nid = "ok"\nport = "/dev/x"\n[[devices]]\nid = "b\\u0007"\n'
            'port = "/dev/y"\n',
            "devices.1.id",
            "U+0007",
        ),
        ('[[devices]]\nid = "a#"\nport = "/dev/x"\n', "devices.0.id", "wildcard '#'"),
    ],
)
def test_a_bad_name_in_the_config_file_stops_the_daemon_at_start(
    tmp_path: Path, toml: str, key: str, says: str
) -> None:
    config = tmp_path / "scotti-daemon.toml"
    source = "" if "[[devices]]" in toml else f'[source]\nport = "{NEVER_OPENED}"\n'
    config.write_text(source + toml, encoding="utf-8")
    line = refused_line(run_daemon("--config", str(config)))
    assert f": {key}: " in line, line
    assert says in line, line


def test_a_config_file_that_is_not_utf8_stops_the_daemon_at_start(tmp_path: Path) -> None:
    config = tmp_path / "scotti-daemon.toml"
    config.write_bytes(b'[source]\nport = "/dev/x"\n[mqtt]\ntopic_prefix = "sc\xffotti"\n')
    line = refused_line(run_daemon("--config", str(config)))
    assert str(config) in line, line


@pytest.mark.parametrize(
    ("variable", "value", "key"),
    [
        ("SCOTTI_MQTT_TOPIC_PREFIX", b"sc\xffotti", "mqtt.topic_prefix"),
        ("SCOTTI_MQTT_TOPIC_PREFIX", b"$SYS/x", "mqtt.topic_prefix"),
        ("SCOTTI_MQTT_DEVICE_ID", b"d\x1b", "mqtt.device_id"),
        ("SCOTTI_MQTT_CLIENT_ID", b"c\xfe", "mqtt.client_id"),
    ],
)
def test_a_bad_name_in_the_environment_stops_the_daemon_at_start(
    variable: str, value: bytes, key: str
) -> None:
    line = refused_line(run_daemon("--port", NEVER_OPENED, env={variable: value}))
    assert f": {key}: " in line, line


def test_every_topic_the_daemon_uses_fits_the_suffix_its_limits_allow() -> None:
    suffixes = [*TOPICS, *CONTROL_TOPICS, "reply/unknown"]
    suffixes += [f"{kind}/{verb}" for verb in REQUESTS for kind in ("cmd", "reply")]
    longest = max(suffixes, key=lambda s: len(s.encode()))
    assert len(longest.encode()) <= TOPIC_SUFFIX_MAX, longest
    assert LONGEST_TOPIC_BYTES <= TOPIC_BYTES_MAX


# The longest names the checks let through: 128 characters of four bytes each.
LONGEST_PREFIX = "\U0001f9b6" * 63 + "/" + "\U0001f9b6" * 64
LONGEST_ID = "d" * DEVICE_ID_MAX


def test_the_longest_names_allowed_make_topics_inside_the_limit() -> None:
    assert len(LONGEST_PREFIX) == TOPIC_PREFIX_MAX
    s = load_settings({"source": {"port": NEVER_OPENED}, "mqtt": {"topic_prefix": LONGEST_PREFIX}})
    topic = s.mqtt.model_copy(update={"device_id": LONGEST_ID}).topic("reply/repetitions/reset")
    assert len(topic.encode()) <= LONGEST_TOPIC_BYTES
    with pytest.raises(ConfigError, match="at most 128 characters"):
        load_settings(
            {"source": {"port": NEVER_OPENED}, "mqtt": {"topic_prefix": "x" + LONGEST_PREFIX}}
        )


@pytest.mark.parametrize(
    "prefix",
    [
        "scotti",
        "site/lab-1/cell_2",
        "gym/M\u00fcnchen/\u5b9e\u9a8c\u5ba4",  # any UTF-8 a broker takes
        "price$/a$b",  # '$' inside a level is an ordinary character
        LONGEST_PREFIX,
    ],
)
@pytest.mark.mosquitto
def test_a_name_the_checks_let_through_reaches_a_subscriber(
    mosquitto: Mosquitto, prefix: str
) -> None:
    """What passes is a topic mosquitto takes: published and received under it."""
    mqtt = load_settings(
        {
            "source": {"port": NEVER_OPENED},
            "mqtt": {"broker": mosquitto.url, "topic_prefix": prefix, "device_id": LONGEST_ID},
        }
    ).mqtt
    assert asyncio.run(_round_trip(mqtt)) == mqtt.topic("status")


async def _round_trip(mqtt: MqttSettings) -> str:
    async with aiomqtt.Client(mqtt.host, mqtt.port, protocol=aiomqtt.ProtocolVersion.V5) as client:
        await client.subscribe(f"{mqtt.topic_prefix}/{mqtt.device_id}/#", qos=1)
        await client.publish(mqtt.topic("status"), b"online", qos=1)
        async with asyncio.timeout(10):
            async for message in client.messages:
                return str(message.topic)
    msg = "no message"
    raise AssertionError(msg)
