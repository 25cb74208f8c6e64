"""``foxglove_schema``: the JSON channels' schemas in the form Foxglove's parser reads,
checked by the parser's rules (tests/support/foxglove_schema.py), and still true of
every message the channels carry."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel
from scotti.daemon.mqtt import messages, schemas
from scotti.daemon.outputs.json_schema import foxglove_schema
from scotti.models.contract import ACTIONS, NO_ACTION

from tests.support.foxglove_schema import misfits, problems
from tests.support.outputs import predictions
from tests.support.sessions import write_synthetic_session

pytest.importorskip("foxglove")
from scotti.daemon.outputs.foxglove_out import DICT_KEYS, LabelMessage, json_message

CHANNEL_MODELS = (schemas.Pose, schemas.Action, schemas.Progress, schemas.Status, LabelMessage)


def test_the_checker_finds_what_the_parser_refuses_in_pydantic_s_own_schemas() -> None:
    # Not a checker that passes everything: pydantic's schemas break each rule.
    found = " ".join(problems(schemas.Action.model_json_schema()))
    for breach in ("$defs", "$ref", "anyOf", "an object without properties"):
        assert breach in found, breach
    found = " ".join(problems(schemas.Pose.model_json_schema()))
    assert "$.keypoints[]: array items of type 'array'" in found
    assert "$.device_seq: type None" in found  # a $ref has no type of its own
    assert "$.unfamiliar_score: type None" in found  # anyOf neither
    assert problems(schemas.Status.model_json_schema())  # prefixItems, no items


@pytest.mark.parametrize("model", CHANNEL_MODELS, ids=lambda m: m.__name__)
def test_every_channel_schema_passes_the_parser_s_rules(model: type[BaseModel]) -> None:
    assert problems(foxglove_schema(model, DICT_KEYS)) == []


def test_what_a_plot_picks_is_in_the_schemas() -> None:
    action = foxglove_schema(schemas.Action, DICT_KEYS)["properties"]
    assert list(action["probabilities"]["properties"]) == list(ACTIONS)
    assert action["device_seq"]["properties"]["left"]["type"] == "integer"  # inlined
    assert action["action"]["type"] == "string"  # ActionName | None: the string, optional
    progress = foxglove_schema(schemas.Progress, DICT_KEYS)
    assert progress["properties"]["progress"]["type"] == "number"
    assert "progress" not in progress["required"]
    assert "repetition" in progress["required"]
    status = foxglove_schema(schemas.Status, DICT_KEYS)["properties"]
    assert status["warming"] == {
        "title": "Warming",
        "description": "[frames in window, frames needed].",
        "type": "array",
        "items": {"type": "integer"},
    }
    assert set(status["feet"]["properties"]) == {"left", "right"}


def test_a_field_it_cannot_type_is_named_not_dropped_in_silence() -> None:
    pose = foxglove_schema(schemas.Pose, DICT_KEYS)
    assert "keypoints" not in pose["properties"]
    assert pose["description"].endswith("still in every message: keypoints.")


def _payloads(session: Path, model: Path) -> list[tuple[str, BaseModel]]:
    out: list[tuple[str, BaseModel]] = []
    made = predictions(session, model)
    # And one withheld, as an empty insole makes it: action, progress and withheld null.
    held = dataclasses.replace(
        made[0], action=NO_ACTION, progress=math.nan, withheld="unloaded", flags=("unloaded",)
    )
    for p in [*made, held]:
        out += messages.frame_payloads(p, 1.0)
    out.append(("status", messages.status("offline", ["stopped"], None)))
    out.append(("labels", LabelMessage(seq=3, action=None, progress=None, repetition=-1)))
    return out


def test_every_message_fits_its_channel_s_schema(tmp_path: Path, tiny_model_path: Path) -> None:
    # The schemas are rewritten, not loosened: each message as the channel logs it (null
    # fields left out) fits its schema and reads back as the same payload; a message
    # with a field of the wrong type or an unknown field does not fit.
    session = write_synthetic_session(tmp_path / "s.scotti", frames=50).path
    payloads = _payloads(session, tiny_model_path)
    by_name: dict[str, Any] = {name: foxglove_schema(type(p), DICT_KEYS) for name, p in payloads}
    for name, payload in payloads:
        message = json_message(payload)
        assert misfits(message, by_name[name]) == [], name
    assert set(by_name) == {"pose", "action", "progress", "status", "labels"}
    withheld = [p for _, p in payloads if isinstance(p, schemas.Progress) and p.action is None]
    assert "progress" not in json_message(withheld[0])  # left out, as the schema allows
    assert misfits({"seq": "three", "repetition": -1}, by_name["labels"]) == [
        "$.seq: 'three' is not integer"
    ]
    assert misfits({"seq": 3, "repetition": -1, "extra": 1}, by_name["labels"]) == [
        "$.extra: not in the schema"
    ]
    assert misfits({"seq": 3}, by_name["labels"]) == ["$.repetition: required, absent"]
