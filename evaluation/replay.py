"""One session file replayed through the daemon's path, predictions aligned with
its labels (``SessionReplay``).

The path is the daemon's, as fast as the model allows: the one frame path
(``firmware_protocol.frame_path``: decode, assemble, pair) -> the model's
streaming window. A prediction made from the
frames t-T..t-1 is for time t, so it is scored against the label record of
the frame after the newest one in its window. The first T labelled frames of
a session therefore have no prediction (the window warms up on T frames and
the first prediction is for frame T).

The model runs one way for every prediction: batched streaming
(``evaluation.segments``), the step graph with its embedding cache on K
segments of the session side by side (``batch=K``, default 16; ``batch=1``
is frame by frame), the predictions the daemon's window makes
(tests/test_evaluation.py compares them with the daemon's own pipeline); a
streaming-native step graph (``KvStepRuntime``) runs the same way with a key/value
cache per segment (``evaluation.kv_segments``).
``every=K`` > 1 scores every K-th prediction time instead, through
the window graph in batches (``evaluation.sampling``): same decoding,
assembly, pairing and restarts, a fraction of the model time.

No torch, no asyncio: ``scotti eval`` and the experiment drivers use it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scotti.evaluation.decoded import DecodeWorker, SessionEnd, decode_session
from scotti.evaluation.errors import EvaluationError
from scotti.evaluation.frames import FrameScores, FrameSet, align
from scotti.evaluation.kv_segments import KvSegmentTrack, kv_window_graph
from scotti.evaluation.sampling import Prediction, SampledTrack
from scotti.evaluation.segments import BATCH, ChunkedSegments, SegmentTrack, quick_gil_handoff
from scotti.firmware_protocol.pairing import PairingConfig
from scotti.firmware_protocol.session import LabelRecord
from scotti.models.contract import ACTIONS
from scotti.models.kv_streaming import StepModel
from scotti.models.ood import flag_counts, withheld
from scotti.models.runtime import ScottiRuntime, load_pair


@dataclass
class SessionReplay:
    """What one session gave: counts along the path and the aligned frames."""

    path: str
    subject: str  # the header's subject id, else the file's stem (as training names it)
    labels: int = 0  # label records in the file
    pairs: int = 0  # paired frames the window took
    predictions: int = 0  # predictions made (with --every K: the scored ones)
    evaluated: int = 0  # predictions whose time has a label
    unlabelled: int = 0  # predictions for a time without a label (the last one, gaps)
    window_restarts: int = 0
    decode_errors: int = 0
    degraded_pairs: int = 0  # pairs with a held, filled or patched foot
    # pairs with a foot zero-filled: silent past the hold (an insole off, or a one-foot file)
    silent_pairs: dict[str, int] = field(default_factory=lambda: {"left": 0, "right": 0})
    step_batches: list[tuple[float, int]] = field(default_factory=list, repr=False)  # (ms, rows)
    window_batches: list[tuple[float, int]] = field(default_factory=list, repr=False)
    model_cpu_s: float = 0.0  # CPU time in the model's graph (this thread), for the rate
    decode_cpu_s: float = 0.0  # CPU time reading and decoding the file (here or a worker)
    frames: FrameSet = field(default_factory=FrameSet.empty, repr=False)
    made: list[Prediction] = field(default_factory=list, repr=False)  # in time order
    # What pooling several sessions keeps once ``drop_predictions`` let the above go:
    scores: FrameScores = field(default_factory=FrameScores.empty, repr=False)
    flags: Counter[str] = field(default_factory=Counter, repr=False)  # models/ood.py flag_counts
    actions: Counter[str] = field(default_factory=Counter, repr=False)  # ``actions_published``

    def drop_predictions(self) -> None:
        """Let the poses and predictions go, keep ``scores`` and ``flags``: a pooled
        evaluation holds ~50 bytes a frame per session instead of ~1 kB."""
        self.frames = FrameSet.empty()
        self.made = []

    def summary(self) -> dict[str, Any]:
        keys = ("path", "subject", "labels", "pairs", "predictions", "evaluated", "unlabelled")
        out = {k: getattr(self, k) for k in keys}
        out |= {
            "window_restarts": self.window_restarts,
            "decode_errors": self.decode_errors,
            "degraded_pairs": self.degraded_pairs,
            "silent_pairs": dict(self.silent_pairs),
            "actions_predicted": dict(self.actions),
        }
        return out


def replay_session(
    path: str | Path,
    runtime: StepModel,
    pairing: PairingConfig | None = None,
    *,
    every: int = 1,
    batch: int = BATCH,
    jobs: int = 1,
) -> SessionReplay:
    """Replay one session file through the daemon's path; score against its labels."""
    return replay_session_models(path, [runtime], pairing, every=every, batch=batch, jobs=jobs)[0]


def window_graphs(runtimes: Sequence[StepModel]) -> list[ScottiRuntime]:
    """The window graph next to each step graph (``--every K``); ``load_pair`` checks that
    it exists and comes from the same export (a one-line ModelError if not)."""
    return [
        load_pair(r.path, r.threads)[1] if isinstance(r, ScottiRuntime) else kv_window_graph(r)
        for r in runtimes
    ]


def segment_track(
    runtime: StepModel,
    out: SessionReplay,
    batch: int,
    jobs: int,
    pool: Executor | None,
    streamed: bool = False,
) -> ChunkedSegments:
    """The batched step loop of the runtime's form (the cache it carries per segment)."""
    track = SegmentTrack if isinstance(runtime, ScottiRuntime) else KvSegmentTrack
    return track(runtime, out, batch, jobs=jobs, pool=pool, streamed=streamed)  # type: ignore[arg-type]


def replay_session_models(
    path: str | Path,
    runtimes: Sequence[StepModel],
    pairing: PairingConfig | None = None,
    *,
    every: int = 1,
    windows: Sequence[ScottiRuntime] | None = None,
    batch: int = BATCH,
    jobs: int = 1,
    pool: Executor | None = None,
    decoder: DecodeWorker | None = None,
) -> list[SessionReplay]:
    """One replay, several models: the bytes are decoded, assembled and paired once,
    and every paired frame goes into each model's own window (nothing is shared
    between the models but the pairs). One ``SessionReplay`` per runtime.

    ``every`` > 1: every ``every``-th prediction through the window graphs
    ``windows`` (default: those next to ``runtimes``) instead of the step graph;
    ``batch`` > 1: segments side by side in each step-graph call (same predictions);
    ``jobs`` > 1: that many groups of them stepped side by side on threads (``pool``,
    else one of ``jobs`` threads for this session), the same predictions again;
    ``decoder``: the file read and decoded in that worker process
    (``evaluation.decoded``) while this one steps the model, the same pairs."""
    if jobs > 1 and pool is None:
        own = ThreadPoolExecutor(jobs, thread_name_prefix="scotti-eval")
        with own, quick_gil_handoff():
            return replay_session_models(
                path,
                runtimes,
                pairing,
                every=every,
                windows=windows,
                batch=batch,
                jobs=jobs,
                pool=own,
                decoder=decoder,
            )
    if every < 1:
        msg = f"--every must be at least 1, got {every}"
        raise EvaluationError(msg)
    if batch < 1:
        msg = f"--batch must be at least 1, got {batch}"
        raise EvaluationError(msg)
    if jobs < 1:
        msg = f"--jobs must be at least 1, got {jobs}"
        raise EvaluationError(msg)
    subject = Path(path).stem  # until the header says otherwise
    streamed = decoder is not None
    tracks: list[SampledTrack | ChunkedSegments]
    if every == 1:
        tracks = [
            segment_track(r, SessionReplay(str(path), subject), batch, jobs, pool, streamed)
            for r in runtimes
        ]
    else:
        graphs = window_graphs(runtimes) if windows is None else windows
        tracks = [SampledTrack(w, every, SessionReplay(str(path), subject)) for w in graphs]
    labels: list[LabelRecord] = []
    end: SessionEnd | None = None
    items = decode_session(path, pairing) if decoder is None else decoder.blocks(path)
    for item in items:
        labels += item.labels
        if isinstance(item, SessionEnd):
            end = item
        else:
            for track in tracks:
                track.take_block(item)
    assert end is not None  # the last item of every session
    for track in tracks:
        track.finish()
        out = track.out
        out.labels = len(labels)
        out.made = track.made
        out.predictions = len(out.made)
        out.window_restarts = track.restarts
        out.subject = _subject_of(end.subject) or out.subject
        out.decode_errors = end.decode_errors
        out.silent_pairs = dict(end.silent_pairs)
        out.decode_cpu_s = end.cpu_seconds
        out.frames, out.unlabelled = align(track.made, labels)
        out.evaluated = len(out.frames)
        out.scores = FrameScores.of(out.frames)
        out.flags = flag_counts(m.flags for m in out.made)
        out.actions = actions_published(out.made)
    return [t.out for t in tracks]


def actions_published(made: Sequence[Prediction]) -> Counter[str]:
    """How often each action would have been published: the most likely one of every
    prediction that no flag withheld (the daemon's rule, ``models.ood.withheld``)."""
    counts: Counter[str] = Counter(dict.fromkeys(ACTIONS, 0))
    counts.update(ACTIONS[int(np.argmax(m.probs))] for m in made if withheld(m.flags) is None)
    return counts


def _subject_of(subject: dict[str, Any] | None) -> str | None:
    if not subject:
        return None
    for key in ("id", "name", "subject_id"):  # the rule training uses, then the file stem
        if key in subject:
            return str(subject[key])
    return None
