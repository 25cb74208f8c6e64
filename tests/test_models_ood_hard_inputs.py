"""Hard inputs through the shipped model (models/scotti-default.onnx, onnxruntime, the
streaming step as the daemon runs it): every output finite, no confident action, and
the flag each must raise.

| input | flag it must raise | why |
|---|---|---|
| all zero | unloaded | both insoles under 100 N for 1 s |
| saturated (every taxel at 4095) | out_of_range | load outside the outline, rail, force |
| one hot taxel, the rest zero | out_of_range | one taxel holds the load |
| uniform noise, full scale | out_of_range | load outside the outline, force |
| a real stream with one foot zero | out_of_range | that insole empty for the whole window |
| a real stream with one foot mirrored | unfamiliar or out_of_range | measured below |

The real stream is a simulated subject the model never saw (a corpus-like lab
session: drawn person, drawn insoles, realistic effects), repaired as the daemon's
pairing repairs a missing foot frame (the previous one held).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scotti.models.contract import FRAME_COLS, MAX_COUNT, WINDOW
from scotti.models.input_checks import OUT_OF_RANGE, UNLOADED
from scotti.models.kv_streaming import (
    KvStepRuntime,
    KvStreamingWindow,
    StepModel,
    open_step_model,
)
from scotti.models.ood import UNFAMILIAR, withheld
from scotti.models.runtime import StepResult
from scotti.models.streaming import StreamingWindow
from scotti.sim.corpus import render_scene, subject_scene
from scotti.sim.subjects import draw_subjects

from tests.support.sim_session import decode_session

SHIPPED = Path(__file__).resolve().parent.parent / "models" / "scotti-default.onnx"
REAL_FRAMES = 200  # 161 predictions per real-stream case


@pytest.fixture(scope="module")
def shipped() -> StepModel:
    runtime = open_step_model(SHIPPED)  # either form, as the daemon opens it
    assert runtime.ood is not None, "the shipped model must carry its OOD statistics"
    return runtime


@pytest.fixture(scope="module")
def real(tmp_path_factory: pytest.TempPathFactory) -> np.ndarray:
    """(REAL_FRAMES, H, 2W) float32 of a squatting and walking subject nobody trained on."""
    person = draw_subjects(1, seed=4242)[0]
    scene = subject_scene(0, person, corpus_seed=4242, minutes_per_action=0.05, effects="realistic")
    assert scene.session is not None
    session = scene.session.model_copy(update={"actions": ["squat", "walking"]})
    path = tmp_path_factory.mktemp("held-out") / "s.ses"
    render_scene(scene.model_copy(update={"session": session}), path)
    decoded = decode_session(path)
    counts = decoded.frame_counts(max(f.seq for f in decoded.frames) + 1)  # -1: never came
    for k in range(1, len(counts)):
        for foot in (0, 1):
            if (counts[k, foot] < 0).any():
                counts[k, foot] = counts[k - 1, foot]  # held, as the daemon's pairing does
    frames = np.concatenate([counts[:, 0], counts[:, 1]], axis=-1).clip(0).astype(np.float32)
    start = len(frames) // 3  # inside the session, past the first standing
    return frames[start : start + REAL_FRAMES]


def stream(runtime: StepModel, frames: np.ndarray) -> list[StepResult]:
    window: StreamingWindow | KvStreamingWindow
    if isinstance(runtime, KvStepRuntime):
        window = KvStreamingWindow(runtime)
    else:
        window = StreamingWindow(runtime)
    results = [window.push(f) for f in frames]
    return [r for r in results if r is not None]


def assert_withheld_and_finite(results: list[StepResult], flag: str) -> None:
    assert results
    for r in results:
        assert np.isfinite(r.pose).all()
        assert np.isfinite(r.action_probs).all()
        assert np.isfinite(r.progress)
        assert r.unfamiliar_score is not None
        assert np.isfinite(r.unfamiliar_score)
        assert flag in r.flags, r.flags
        assert withheld(r.flags) is not None  # no confident action is published


def repeated(frame: np.ndarray, n: int = WINDOW + 4) -> np.ndarray:
    return np.repeat(frame[None].astype(np.float32), n, axis=0)


def test_all_zero_is_unloaded(shipped: StepModel) -> None:
    results = stream(shipped, repeated(np.zeros(shipped.frame_shape)))
    assert_withheld_and_finite(results, UNLOADED)
    assert all(withheld(r.flags) == UNLOADED for r in results)


@pytest.mark.parametrize("case", ["saturated", "hot_taxel", "uniform_noise"])
def test_implausible_maps_are_out_of_range(shipped: StepModel, case: str) -> None:
    shape = shipped.frame_shape
    if case == "saturated":
        frames = repeated(np.full(shape, MAX_COUNT))
    elif case == "hot_taxel":
        hot = np.zeros(shape)
        hot[10, FRAME_COLS + 8] = MAX_COUNT
        frames = repeated(hot)
    else:
        rng = np.random.default_rng(0)
        frames = rng.uniform(0, MAX_COUNT, (WINDOW + 4, *shape)).astype(np.float32)
    assert_withheld_and_finite(stream(shipped, frames), OUT_OF_RANGE)


def test_the_real_stream_is_not_flagged_by_the_input_rules(
    shipped: StepModel, real: np.ndarray
) -> None:
    results = stream(shipped, real)
    assert len(results) == REAL_FRAMES - WINDOW + 1
    assert not any({UNLOADED, OUT_OF_RANGE} & set(r.flags) for r in results)
    assert all(np.isfinite(r.pose).all() for r in results)


@pytest.mark.parametrize("foot", ["left", "right"])
def test_one_foot_zero_is_out_of_range(shipped: StepModel, real: np.ndarray, foot: str) -> None:
    frames = real.copy()
    frames[..., slice(0, FRAME_COLS) if foot == "left" else slice(FRAME_COLS, None)] = 0.0
    assert_withheld_and_finite(stream(shipped, frames), OUT_OF_RANGE)


@pytest.mark.parametrize("foot", ["left", "right"])
def test_a_mirrored_foot_is_caught_by_the_rules_or_the_unfamiliar_score(
    shipped: StepModel, real: np.ndarray, foot: str
) -> None:
    """Medial and lateral swapped (an insole in the other shoe): no rule names it,
    but the map spills outside the outline and the window is unlike the training data.
    Not every window: the corpus figures are in docs/ood.md."""
    frames = real.copy()
    cols = slice(0, FRAME_COLS) if foot == "left" else slice(FRAME_COLS, None)
    frames[..., cols] = real[..., cols][..., ::-1]
    results = stream(shipped, frames)
    caught = [withheld(r.flags) is not None for r in results]
    by_score = [UNFAMILIAR in r.flags for r in results]
    assert all(np.isfinite(r.pose).all() for r in results)
    share = f"{np.mean(caught):.3f} caught, {np.mean(by_score):.3f} unfamiliar"
    assert np.mean(caught) >= 0.8, share  # corpus: 89.6 % (left), 92.4 % (right)
