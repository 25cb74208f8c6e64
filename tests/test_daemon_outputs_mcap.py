"""``scotti session export --mcap`` read back with the mcap reader: topics, Foxglove
schemas, log times on the recording's clock, and the pressure images equal to
the counts the session carries."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scotti.cli.main import main as scotti
from scotti.firmware_protocol.packets import Foot
from scotti.models.contract import ACTIONS, BONES, FRAME_COLS, FRAME_ROWS, NUM_KEYPOINTS

from tests.support.outputs import read_mcap
from tests.support.sessions import PERIOD_NS, synthetic_counts, write_synthetic_session

pytest.importorskip("foxglove")
mcap_reader = pytest.importorskip("mcap.reader")

FRAMES = 64


@pytest.fixture(scope="module")
def exported(
    tmp_path_factory: pytest.TempPathFactory, tiny_model_path: Path
) -> tuple[Path, Path, Any]:
    folder = tmp_path_factory.mktemp("mcap")
    session = write_synthetic_session(folder / "s.scotti", frames=FRAMES)
    out = folder / "s.mcap"
    model = str(tiny_model_path)
    code = scotti(["session", "export", str(session.path), "--mcap", str(out), "--model", model])
    assert code == 0
    return session.path, out, read_mcap(out)


def test_export_has_the_channels_in_foxglove_schemas(exported: tuple[Path, Path, Any]) -> None:
    _, _, (messages, schemas, metadata) = exported
    assert schemas["/pressure/left"] == schemas["/pressure/right"] == "foxglove.RawImage"
    assert schemas["/skeleton"] == "foxglove.SceneUpdate"
    assert {"/pose", "/action", "/progress", "/status"} <= set(schemas)
    n = len(messages["/action"])
    assert n > 0
    for topic in ("/pressure/left", "/pressure/right", "/skeleton", "/pose", "/progress"):
        assert len(messages[topic]) == n, topic
    assert metadata[0].name == "scotti"
    assert metadata[0].metadata["session"] == "s.scotti"


def test_log_times_follow_the_recording_not_the_export(
    exported: tuple[Path, Path, Any],
) -> None:
    _, _, (messages, _, _) = exported
    times = np.array([t for t, _ in messages["/action"]])
    steps = np.diff(times)
    # One prediction per recorded frame, 62.5 ms apart on the recording's clock, however
    # fast the export ran.
    assert np.median(steps) == pytest.approx(PERIOD_NS, rel=0.02)
    for t, action in messages["/action"]:
        assert action["host_wall_ns"] == t


def test_pressure_images_carry_the_sessions_counts(exported: tuple[Path, Path, Any]) -> None:
    _, _, (messages, _, _) = exported
    for (t_img, left), (t_right, right), (t_act, action) in zip(
        messages["/pressure/left"], messages["/pressure/right"], messages["/action"], strict=True
    ):
        assert t_img == t_right == t_act
        assert (left.width, left.height, left.encoding) == (FRAME_COLS, FRAME_ROWS, "mono16")
        seq = action["device_seq"]
        got_left = np.frombuffer(left.data, dtype="<u2").reshape(FRAME_ROWS, FRAME_COLS)
        got_right = np.frombuffer(right.data, dtype="<u2").reshape(FRAME_ROWS, FRAME_COLS)
        np.testing.assert_array_equal(got_left, synthetic_counts(Foot.LEFT, seq["left"]))
        np.testing.assert_array_equal(got_right, synthetic_counts(Foot.RIGHT, seq["right"]))


def test_skeleton_is_the_pose_as_spheres_and_bone_lines(exported: tuple[Path, Path, Any]) -> None:
    _, _, (messages, _, _) = exported
    for (_, scene), (_, pose), (_, action) in zip(
        messages["/skeleton"], messages["/pose"], messages["/action"], strict=True
    ):
        (entity,) = scene.entities
        assert entity.frame_id == "pose"
        centres = [[s.pose.position.x, s.pose.position.y, s.pose.position.z]
                   for s in entity.spheres]  # fmt: skip
        assert len(centres) == NUM_KEYPOINTS
        np.testing.assert_allclose(centres, pose["keypoints"], atol=1e-6)
        (lines,) = entity.lines
        assert len(lines.points) == 2 * len(BONES)
        meta = {kv.key: kv.value for kv in entity.metadata}
        assert meta["seq"] == str(action["seq"])
        assert meta["device_time_us"] == str(action["device_time_us"])
        assert set(action["probabilities"]) == set(ACTIONS)
        assert sum(action["probabilities"].values()) == pytest.approx(1.0, abs=1e-4)


def test_export_of_a_broken_file_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.scotti"
    bad.write_bytes(b"not a session")
    assert scotti(["session", "export", str(bad), "--mcap", str(tmp_path / "o.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("scotti session export: ")
    assert err.count("\n") == 1


def test_a_labelled_session_carries_its_ground_truth(exported: tuple[Path, Path, Any]) -> None:
    _, _, (messages, schemas, _) = exported
    assert schemas["/labels/skeleton"] == "foxglove.SceneUpdate"
    labels = [m for _, m in messages["/labels"]]
    assert [lb["seq"] for lb in labels] == list(range(FRAMES))
    # write_synthetic_session labels frame i with action i // 16 and progress (i % 16) / 16.
    assert [lb["action"] for lb in labels] == [
        ACTIONS[i // 16 % len(ACTIONS)] for i in range(FRAMES)
    ]
    assert [lb["progress"] for lb in labels] == [(i % 16) / 16 for i in range(FRAMES)]
    truth_times = [t for t, _ in messages["/labels/skeleton"]]
    assert np.diff(truth_times).tolist() == [PERIOD_NS] * (FRAMES - 1)
    (entity,) = messages["/labels/skeleton"][0][1].entities
    assert entity.id == "ground_truth"
    assert len(entity.spheres) == NUM_KEYPOINTS


def _file_order(path: Path) -> list[tuple[str, int]]:
    """(topic, log time) of every message as it lies in the file, front to back."""
    with path.open("rb") as f:
        reader = mcap_reader.make_reader(f)
        return [(c.topic, m.log_time) for _, c, m in reader.iter_messages(log_time_order=False)]


def test_messages_lie_in_the_file_in_log_time_order_labels_among_them(
    exported: tuple[Path, Path, Any],
) -> None:
    _, out, _ = exported
    order = _file_order(out)
    times = [t for _, t in order]
    assert times == sorted(times)  # a reader streaming the file sees them as they happened
    topics = [topic for topic, _ in order]
    actions = [i for i, topic in enumerate(topics) if topic == "/action"]
    between = topics[actions[0] : actions[-1]]
    # Interleaved, not all written before or after the predictions: every label of the
    # span the predictions cover lies among them.
    spanned = [t for topic, t in order if topic == "/labels" and times[actions[0]] < t]
    spanned = [t for t in spanned if t < times[actions[-1]]]
    assert between.count("/labels") == len(spanned) > 10
    assert topics.count("/labels") == FRAMES


def test_every_json_channel_carries_a_schema_foxglove_s_parser_reads(
    exported: tuple[Path, Path, Any],
) -> None:
    import json

    from tests.support.foxglove_schema import misfits, problems

    _, out, (messages, _, _) = exported
    with out.open("rb") as f:
        summary = mcap_reader.make_reader(f).get_summary()
    assert summary is not None
    json_channels = {c.topic: c for c in summary.channels.values() if c.message_encoding == "json"}
    assert set(json_channels) == {"/pose", "/action", "/progress", "/status", "/labels"}
    for topic, channel in json_channels.items():
        schema_record = summary.schemas[channel.schema_id]
        assert schema_record.encoding == "jsonschema", topic
        schema = json.loads(schema_record.data)
        assert problems(schema) == [], topic
        for _, message in messages[topic]:
            assert misfits(message, schema) == [], topic


def test_the_export_names_its_model_in_the_scotti_record(
    exported: tuple[Path, Path, Any], tiny_model_path: Path
) -> None:
    import hashlib

    _, _, (_, _, metadata) = exported
    (record,) = [m for m in metadata if m.name == "scotti"]
    assert record.metadata["model"] == tiny_model_path.name
    assert (
        record.metadata["model_sha256"] == hashlib.sha256(tiny_model_path.read_bytes()).hexdigest()
    )


def test_an_existing_output_is_refused_unless_force(
    tmp_path: Path, tiny_model_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session = write_synthetic_session(tmp_path / "s.scotti", frames=44).path
    out = tmp_path / "s.mcap"
    out.write_bytes(b"yesterday's export")
    args = ["session", "export", str(session), "--mcap", str(out), "--model", str(tiny_model_path)]
    assert scotti(args) == 2
    err = capsys.readouterr().err
    assert err == f"scotti session export: {out} exists; --force replaces it\n"
    assert out.read_bytes() == b"yesterday's export"
    assert scotti([*args, "--force"]) == 0
    assert out.read_bytes().endswith(b"\x89MCAP0\r\n")


def test_export_with_the_shipped_model_of_either_form(tmp_path: Path) -> None:
    """No --model: the shipped default, opened as the daemon opens it (the streaming-native
    form's step graph as well as the paper form's)."""
    from scotti.daemon.settings import default_model_path
    from scotti.models.kv_streaming import open_step_model

    session = write_synthetic_session(tmp_path / "s.scotti", frames=FRAMES)
    out = tmp_path / "s.mcap"
    assert scotti(["session", "export", str(session.path), "--mcap", str(out)]) == 0
    messages, _, metadata = read_mcap(out)
    assert len(messages["/action"]) > 0
    shipped = open_step_model(default_model_path())
    assert metadata[0].metadata["model_sha256"] == shipped.sha256
