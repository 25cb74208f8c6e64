"""Per-frame payloads as plain dicts (what the publisher encodes) against the schemas.

The publisher encodes ``messages.frame_dicts`` without building a pydantic
model per message. Here the same predictions go both ways: the dicts encoded
(``schemas.encode_dict``) must be the bytes the models encode to, and must
validate against the models, for confident, withheld, standing and
uncalibrated predictions, with and without pressure, in JSON and msgpack.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Literal

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt import messages
from scotti.daemon.mqtt.latency_slot import LatencySlot
from scotti.daemon.mqtt.schemas import TOPICS, decode, encode, encode_dict
from scotti.daemon.tools.bench_publish import make_prediction
from scotti.models.contract import ACTIONS, NO_ACTION

FORMATS: tuple[Literal["json", "msgpack"], ...] = ("json", "msgpack")


@functools.cache
def predictions() -> tuple[Prediction, ...]:
    rng = np.random.default_rng(3)
    made = [make_prediction(rng, seq) for seq in range(40)]
    first = made[0]
    standing = ACTIONS.index("standing")
    return (
        *made,
        dataclasses.replace(  # withheld: no action, no progress, the count kept
            first,
            action=NO_ACTION,
            withheld="unfamiliar",
            flags=("unfamiliar",),
            progress=float("nan"),
            repetition=4,
            unfamiliar_score=None,
        ),
        dataclasses.replace(first, action=standing, progress=float("nan"), repetition=-1),
        dataclasses.replace(first, withheld="unloaded", flags=("unloaded", "left_filled")),
        dataclasses.replace(first, unfamiliar_score=float("nan")),  # null in JSON
    )


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("pressure", [0, 1, 3])
def test_encoded_dicts_are_the_models_bytes_and_validate(
    fmt: Literal["json", "msgpack"], pressure: int
) -> None:
    checked = 0
    for p in predictions():
        for name, data in messages.frame_dicts(p, 12.345, pressure):
            raw = encode_dict(data, fmt)
            decoded = decode(TOPICS[name], raw, fmt)  # validates: types, ranges, no extras
            assert encode(decoded, fmt) == raw, name
            assert encode(TOPICS[name].model_validate(data), fmt) == raw, name
            checked += 1
    assert checked == len(predictions()) * (4 if pressure else 3)


@pytest.mark.parametrize("fmt", FORMATS)
def test_latency_written_in_later_gives_the_same_bytes(fmt: Literal["json", "msgpack"]) -> None:
    p = predictions()[1]
    later = dict(messages.frame_payloads(p, 7.25))
    for name, data in messages.frame_dicts(p, 0.0):
        assert LatencySlot.cut(encode_dict(data, fmt), fmt).fill(7.25) == encode(later[name], fmt)


def test_withheld_and_standing_say_so() -> None:
    *_, withheld, standing, unloaded, _nan = predictions()
    action = dict(messages.frame_dicts(withheld, 0.0))["action"]
    assert (action["action"], action["withheld"], action["confidence"]) == (None, "unfamiliar", 0.0)
    progress = dict(messages.frame_dicts(withheld, 0.0))["progress"]
    assert (progress["progress"], progress["repetition"]) == (None, 4)
    standing_progress = dict(messages.frame_dicts(standing, 0.0))["progress"]
    assert (standing_progress["action"], standing_progress["progress"]) == ("standing", None)
    assert dict(messages.frame_dicts(unloaded, 0.0))["pose"]["flags"] == ["unloaded", "left_filled"]


@settings(max_examples=150, deadline=None)
@given(
    score=st.floats(allow_nan=True, allow_infinity=True),
    pose=st.lists(st.floats(width=32), min_size=57, max_size=57),
)
def test_any_float_is_written_as_pydantic_writes_it(score: float, pose: list[float]) -> None:
    p = dataclasses.replace(
        predictions()[0],
        unfamiliar_score=score,
        pose=np.asarray(pose, dtype=np.float32).reshape(19, 3),
    )
    for name, data in messages.frame_dicts(p, 0.0):
        model = TOPICS[name].model_validate(data)
        assert encode_dict(data, "json") == encode(model, "json"), name
