"""ScottiRuntime on the real tiny export: inference, and refusal of models that do not fit."""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnx
import pytest
from scotti.models import contract as c
from scotti.models.errors import ModelContractError, ModelError, ModelInputError
from scotti.models.runtime import ScottiRuntime, load_pair, softmax, window_graph_for

from tests.support.fixtures_models import TINY_V1_STEP

FRAME = (c.FRAME_ROWS, 2 * c.FRAME_COLS)


@functools.cache
def _proto_bytes(path: Path) -> bytes:
    return path.read_bytes()


def frames(n: int, seed: int = 0) -> np.ndarray:
    """Plausible raw counts: mostly light contact, some taxels near saturation."""
    rng = np.random.default_rng(seed)
    return (rng.gamma(0.6, 600.0, (n, *FRAME)).clip(0, c.MAX_COUNT)).astype(np.float32)


@pytest.fixture
def step_rt(tiny_model_path: Path) -> ScottiRuntime:
    return ScottiRuntime(tiny_model_path)


@pytest.fixture
def window_rt(tiny_model_path: Path) -> ScottiRuntime:
    return ScottiRuntime(window_graph_for(tiny_model_path))


@pytest.fixture
def edited(tiny_model_path: Path, tmp_path: Path) -> Callable[..., Path]:
    """Write a copy of the step graph with its metadata or graph changed by ``edit``."""

    def write(edit: Callable[[onnx.ModelProto, dict[str, str]], None]) -> Path:
        model = onnx.load_from_string(_proto_bytes(tiny_model_path))
        meta = {p.key: p.value for p in model.metadata_props}
        edit(model, meta)
        del model.metadata_props[:]
        for key, value in meta.items():
            entry = model.metadata_props.add()
            entry.key, entry.value = key, value
        out = tmp_path / "bad.onnx"
        onnx.save(model, str(out))
        return out

    return write


def test_loads_the_step_graph_and_reports_what_it_loaded(
    step_rt: ScottiRuntime, tiny_model_path: Path
) -> None:
    assert step_rt.graph == "step"
    assert step_rt.window == c.WINDOW
    assert step_rt.embed_dim >= 1
    assert step_rt.frame_shape == FRAME
    assert step_rt.path == tiny_model_path
    assert step_rt.sha256 == hashlib.sha256(tiny_model_path.read_bytes()).hexdigest()
    assert isinstance(step_rt.card, dict)
    assert step_rt.card  # the exporter embeds the card
    card_file = tiny_model_path.with_name(tiny_model_path.name.replace(".onnx", ".card.json"))
    if card_file.exists():
        assert json.loads(card_file.read_text()).get("name") == step_rt.card.get("name")


def test_step_outputs(step_rt: ScottiRuntime) -> None:
    past = np.random.default_rng(1).normal(0, 1, (c.WINDOW - 1, step_rt.embed_dim))
    out = step_rt.step(frames(1)[0], past)
    assert out.pose.shape == (c.NUM_KEYPOINTS, 3)
    assert out.action_logits.shape == out.action_probs.shape == (c.NUM_ACTIONS,)
    assert out.embedding.shape == (step_rt.embed_dim,)
    assert out.pose.dtype == out.embedding.dtype == np.float32
    assert out.action_probs.sum() == pytest.approx(1.0, abs=1e-5)
    assert int(out.action_probs.argmax()) == int(out.action_logits.argmax())
    assert 0.0 <= out.progress <= 1.0
    assert all(np.all(np.isfinite(a)) for a in (out.pose, out.action_logits, out.embedding))


def test_new_embedding_depends_on_the_frame_only(step_rt: ScottiRuntime) -> None:
    # What makes the cache valid: a frame's embedding does not see the past.
    frame = frames(1, seed=2)[0]
    rng = np.random.default_rng(3)
    e = step_rt.embed_dim
    a = step_rt.step(frame, rng.normal(0, 1, (c.WINDOW - 1, e)))
    b = step_rt.step(frame, np.zeros((c.WINDOW - 1, e)))
    other = step_rt.step(frames(1, seed=4)[0], np.zeros((c.WINDOW - 1, e)))
    np.testing.assert_allclose(a.embedding, b.embedding, atol=1e-5)
    assert not np.allclose(a.embedding, other.embedding)


def test_hard_inputs_stay_finite(step_rt: ScottiRuntime) -> None:
    past = np.zeros((c.WINDOW - 1, step_rt.embed_dim), np.float32)
    for frame in (
        np.zeros(FRAME),  # nobody on the insoles
        np.full(FRAME, c.MAX_COUNT),  # every taxel saturated
        np.full(FRAME, 1e9),  # a corrupt value far beyond the protocol's range
        np.full(FRAME, -5.0),  # below zero (bad calibration)
    ):
        out = step_rt.step(frame, past)
        assert np.all(np.isfinite(out.pose))
        assert np.all(np.isfinite(out.action_probs))
        assert 0.0 <= out.progress <= 1.0


def test_step_refuses_wrong_shapes(step_rt: ScottiRuntime) -> None:
    past = np.zeros((c.WINDOW - 1, step_rt.embed_dim), np.float32)
    with pytest.raises(ModelInputError, match="frame must be"):
        step_rt.step(np.zeros((c.FRAME_ROWS, c.FRAME_COLS)), past)
    with pytest.raises(ModelInputError, match="past embeddings must be"):
        step_rt.step(np.zeros(FRAME), past[:-1])


def test_each_graph_does_only_its_own_job(step_rt: ScottiRuntime, window_rt: ScottiRuntime) -> None:
    with pytest.raises(ModelError, match=r"needs the window graph .*\.window\.onnx"):
        step_rt.run_windows(frames(c.WINDOW)[None])
    with pytest.raises(ModelError, match="step\\(\\) needs the step graph"):
        window_rt.step(np.zeros(FRAME), np.zeros((c.WINDOW - 1, step_rt.embed_dim)))


def test_run_windows_batches_and_chunks(window_rt: ScottiRuntime) -> None:
    x = frames(3 * c.WINDOW, seed=5).reshape(3, c.WINDOW, *FRAME)
    whole = window_rt.run_windows(x)
    chunked = window_rt.run_windows(x, batch_size=2)
    assert whole.pose.shape == (3, c.NUM_KEYPOINTS, 3)
    assert whole.action_probs.shape == (3, c.NUM_ACTIONS)
    assert whole.progress.shape == (3,)
    np.testing.assert_allclose(whole.pose, chunked.pose, atol=1e-5)
    np.testing.assert_allclose(whole.action_logits, chunked.action_logits, atol=1e-5)
    np.testing.assert_allclose(whole.action_probs.sum(axis=1), 1.0, atol=1e-5)
    single = window_rt.run_windows(x[1:2])
    np.testing.assert_allclose(single.progress, whole.progress[1:2], atol=1e-5)
    empty = window_rt.run_windows(np.zeros((0, c.WINDOW, *FRAME)))
    assert empty.pose.shape == (0, c.NUM_KEYPOINTS, 3)
    with pytest.raises(ModelInputError, match="frames must be"):
        window_rt.run_windows(x[:, :-1])


def test_threads_do_not_change_results(tiny_model_path: Path, step_rt: ScottiRuntime) -> None:
    two = ScottiRuntime(tiny_model_path, threads=2)
    assert two.threads == 2
    past = np.ones((c.WINDOW - 1, step_rt.embed_dim), np.float32)
    frame = frames(1, seed=6)[0]
    np.testing.assert_allclose(
        two.step(frame, past).pose, step_rt.step(frame, past).pose, atol=1e-5
    )
    with pytest.raises(ModelError, match="threads must be at least 1"):
        ScottiRuntime(tiny_model_path, threads=0)


def test_softmax_is_stable() -> None:
    probs = softmax(np.array([1000.0, 0.0, -1000.0]))
    np.testing.assert_allclose(probs, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(softmax(np.zeros((2, 4))), 0.25)


def test_window_graph_naming() -> None:
    assert window_graph_for("models/scotti.onnx") == Path("models/scotti.window.onnx")
    assert window_graph_for("m/a.int8.onnx") == Path("m/a.int8.window.onnx")
    assert ScottiRuntime.window_graph_for("x.onnx") == Path("x.window.onnx")


def test_load_pair(tiny_model_path: Path, tmp_path: Path) -> None:
    step, window = load_pair(tiny_model_path)
    assert (step.graph, window.graph) == ("step", "window")
    assert window.path == window_graph_for(tiny_model_path)
    lonely = tmp_path / "lonely.onnx"
    lonely.write_bytes(tiny_model_path.read_bytes())
    with pytest.raises(ModelError, match=r"no window graph lonely\.window\.onnx"):
        load_pair(lonely)
    # A window graph handed over as the step graph is refused.
    swapped = tmp_path / "swapped.onnx"
    swapped.write_bytes(window_graph_for(tiny_model_path).read_bytes())
    (tmp_path / "swapped.window.onnx").write_bytes(window_graph_for(tiny_model_path).read_bytes())
    with pytest.raises(ModelContractError, match="must be a step graph"):
        load_pair(swapped)


# --- models that do not fit the contract ------------------------------------


def _set(key: str, value: str) -> Callable[[onnx.ModelProto, dict[str, str]], None]:
    def edit(_model: onnx.ModelProto, meta: dict[str, str]) -> None:
        meta[key] = value

    return edit


def _drop(key: str) -> Callable[[onnx.ModelProto, dict[str, str]], None]:
    def edit(_model: onnx.ModelProto, meta: dict[str, str]) -> None:
        del meta[key]

    return edit


def _drop_all(_model: onnx.ModelProto, meta: dict[str, str]) -> None:
    meta.clear()


def _rename_input(model: onnx.ModelProto, _meta: dict[str, str]) -> None:
    old, new = c.STEP_INPUT_FRAME, "pressure"
    for value in model.graph.input:
        if value.name == old:
            value.name = new
    for node in model.graph.node:
        for i, name in enumerate(node.input):
            if name == old:
                node.input[i] = new


def _pose_with_17_keypoints(model: onnx.ModelProto, _meta: dict[str, str]) -> None:
    """Really predict 17 keypoints: slice the pose output before it leaves the graph."""
    graph = model.graph
    for node in graph.node:
        for i, name in enumerate(node.output):
            if name == c.OUTPUT_POSE:
                node.output[i] = "pose_19"
    for name, value in (("starts", 0), ("ends", 17), ("axes", 1)):
        graph.initializer.append(
            onnx.helper.make_tensor(f"slice_{name}", onnx.TensorProto.INT64, [1], [value])
        )
    graph.node.append(
        onnx.helper.make_node(
            "Slice", ["pose_19", "slice_starts", "slice_ends", "slice_axes"], [c.OUTPUT_POSE]
        )
    )
    for value in graph.output:
        if value.name == c.OUTPUT_POSE:
            value.type.tensor_type.shape.dim[1].dim_value = 17


KEYPOINTS_17 = json.dumps(list(c.KEYPOINTS[:17]))
KEYPOINTS_RENAMED = json.dumps(["head", *c.KEYPOINTS[1:]])
ACTIONS_SWAPPED = json.dumps([c.ACTIONS[1], c.ACTIONS[0], *c.ACTIONS[2:]])


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (_set(c.META_CONTRACT_VERSION, "3"), "model has contract version 3, this runtime needs 2"),
        (_set(c.META_KEYPOINTS, KEYPOINTS_17), "model has 17 keypoints, contract needs 19"),
        (_set(c.META_KEYPOINTS, KEYPOINTS_RENAMED), "keypoint 0 is 'head', contract needs 'nose'"),
        (_set(c.META_ACTIONS, ACTIONS_SWAPPED), "action 0 is 'lunge', contract needs 'squat'"),
        (_set(c.META_ACTIONS, "squat,lunge"), "scotti.actions is not a JSON list"),
        (_set(c.META_WINDOW, "32"), "model has window T=32, contract needs 40"),
        (_set(c.META_WINDOW, "forty"), "scotti.window is 'forty', not a positive integer"),
        (
            _set(c.META_FRAME_ROWS, "30"),
            "model frame is 30x22 taxels per foot, contract needs 32x22",
        ),
        (_set(c.META_GRAPH, "encoder"), "graph kind is 'encoder'"),
        (_set(c.META_GRAPH, "window"), "model inputs are"),
        (_set(c.META_EMBED_DIM, "7"), "'past_embeddings' has shape"),
        (_set(c.META_CARD, "[1, 2]"), "scotti.card is not a JSON object"),
        (_drop(c.META_ACTIONS), "model metadata lacks scotti.actions"),
        (_drop_all, "no scotti.* metadata: not a SCOTTI export"),
        (_rename_input, "model inputs are ['past_embeddings', 'pressure']"),
        (_pose_with_17_keypoints, "output 'pose' has shape"),
    ],
)
def test_refuses_a_model_that_does_not_fit(
    edited: Callable[..., Path],
    edit: Callable[[onnx.ModelProto, dict[str, str]], None],
    message: str,
) -> None:
    path = edited(edit)
    with pytest.raises(ModelContractError) as caught:
        ScottiRuntime(path)
    text = str(caught.value)
    assert message in text
    assert text.startswith("bad.onnx: ")
    assert "\n" not in text


def test_refuses_a_real_contract_v1_model_in_one_line() -> None:
    """The tiny model as exported before standing (8 action logits, contract version 1)."""
    old = TINY_V1_STEP
    meta = {p.key: p.value for p in onnx.load(str(old)).metadata_props}
    assert meta[c.META_CONTRACT_VERSION] == "1"
    assert len(json.loads(meta[c.META_ACTIONS])) == 8
    with pytest.raises(ModelContractError) as caught:
        ScottiRuntime(old)
    text = str(caught.value)
    assert text.startswith(
        f"scotti-tiny.onnx: model has contract version 1, this runtime needs {c.CONTRACT_VERSION} "
    )
    assert "\n" not in text


def test_a_card_is_optional(edited: Callable[..., Path]) -> None:
    assert ScottiRuntime(edited(_drop(c.META_CARD))).card == {}


def test_missing_garbage_and_truncated_files(tiny_model_path: Path, tmp_path: Path) -> None:
    with pytest.raises(ModelError, match="does not exist") as missing:
        ScottiRuntime(tmp_path / "nope.onnx")
    assert not isinstance(missing.value, ModelContractError)
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"\x00\xff this is not a protobuf" * 40)
    truncated = tmp_path / "truncated.onnx"
    data = tiny_model_path.read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    empty = tmp_path / "empty.onnx"
    empty.write_bytes(b"")
    for bad in (garbage, truncated, empty, tmp_path):
        with pytest.raises(ModelError) as caught:
            ScottiRuntime(bad)
        assert "\n" not in str(caught.value)
        assert str(bad) in str(caught.value)


def test_step_batch_gives_each_row_what_step_gives_it(
    step_rt: ScottiRuntime, window_rt: ScottiRuntime
) -> None:
    rng = np.random.default_rng(5)
    x = frames(3, seed=5)
    past = rng.normal(size=(3, step_rt.window - 1, step_rt.embed_dim)).astype(np.float32)
    rows = step_rt.step_batch(x, past)
    assert len(rows) == 3
    for i, row in enumerate(rows):
        alone = step_rt.step(x[i], past[i])
        np.testing.assert_allclose(row.pose, alone.pose, atol=1e-5)
        np.testing.assert_allclose(row.embedding, alone.embedding, atol=1e-5)
        np.testing.assert_allclose(row.action_probs, alone.action_probs, atol=1e-5)
    with pytest.raises(ModelInputError, match="past embeddings must be"):
        step_rt.step_batch(x, past[:2])
    with pytest.raises(ModelInputError, match="frames must be"):
        step_rt.step_batch(x[:, :3], past)
    with pytest.raises(ModelError, match="needs the step graph"):
        window_rt.step_batch(x, past)


def test_loading_a_model_turns_onnxruntime_telemetry_off(tiny_model_path: Path) -> None:
    """onnxruntime keeps no readable telemetry state, so the call itself is watched: a
    profile hook sees every C function the load calls, in this thread, unmocked."""
    import sys

    import onnxruntime as ort

    called: list[object] = []

    def watch(frame: object, event: str, arg: object) -> None:
        if event == "c_call" and arg in (ort.disable_telemetry_events, ort.enable_telemetry_events):
            called.append(arg)

    sys.setprofile(watch)
    try:
        ScottiRuntime(tiny_model_path)
    finally:
        sys.setprofile(None)
    assert called, "the model loaded without disable_telemetry_events()"
    assert called[-1] is ort.disable_telemetry_events  # and nothing turned it back on
