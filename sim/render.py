"""Pictures of a session: pressure maps, skeleton, action and progress.

Reads any session file with labels (simulated or labelled recordings): the
packets go through the daemon's own frame path (``firmware_protocol.frame_path``),
so the feet drawn are the pairs the model is shown (a lost frame held or
zero-filled as the daemon does); the labels give the pose (pose frame: x
forward, y left, z up) and the action and progress.

Foot maps are drawn as seen from above with the toes up. The data's column 0
is medial on both insoles, so the right foot is drawn as sent and the left
foot mirrored, giving an anatomical pair (big toes towards the middle).
"""

from __future__ import annotations

import os
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final

import numpy as np
from scotti.firmware_protocol.assembly import FootFrame
from scotti.firmware_protocol.frame_path import FramePath, FrameWatch, stream_pairs
from scotti.firmware_protocol.pairing import PairedFrame
from scotti.firmware_protocol.session import (
    LabelRecord,
    PacketRecord,
    SessionHeader,
    SourceFrameRecord,
    iter_records,
)
from scotti.models.contract import ACTIONS, BONES, KP, MAX_COUNT, NO_ACTION
from scotti.sim import SimError

_MARGIN_NS: Final = 1_000_000_000  # packets read around the span, for late or early feet
_SNAPSHOTS: Final = 4
_GIF_FPS: Final = 8.0


class RenderError(SimError):
    """The session cannot be drawn (no labels in the span, unreadable file)."""


@dataclass(frozen=True)
class Span:
    """The labelled frames of a time span of a session."""

    time_s: np.ndarray  # (n,) since the session's first label
    counts: np.ndarray  # (n, 2, rows, cols) uint16 as the daemon pairs them, zeros: no pair
    keypoints: np.ndarray  # (n, 19, 3) pose frame
    action: np.ndarray  # (n,)
    progress: np.ndarray  # (n,)
    header: SessionHeader
    # Imported sessions: source frames as the other insole stored them (thinned),
    # their times on the same axis as ``time_s``; empty for the others.
    source_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    source_frames: list[np.ndarray] = field(default_factory=list)  # each (2, rows, cols)


def load_span(
    path: str | os.PathLike[str], start_s: float = 0.0, duration_s: float | None = None
) -> Span:
    """Frames and labels from ``start_s`` for ``duration_s`` (None: to the end)."""
    header: SessionHeader | None = None
    labels: list[LabelRecord] = []
    chunks: list[tuple[int, bytes]] = []
    early: deque[tuple[int, bytes]] = deque()
    sources: list[SourceFrameRecord] = []
    t0: int | None = None
    begin = end = 0
    try:
        for record in iter_records(path, source_frames=True):
            if isinstance(record, SessionHeader):
                header = record
            elif isinstance(record, LabelRecord):
                if t0 is None:
                    t0 = record.t_ns
                    begin = t0 + round(start_s * 1e9)
                    end = begin + round(duration_s * 1e9) if duration_s is not None else 2**62
                if begin <= record.t_ns < end:
                    labels.append(record)
                elif record.t_ns >= end + _MARGIN_NS:
                    break
            elif isinstance(record, SourceFrameRecord):
                sources.append(record)
            elif isinstance(record, PacketRecord) and t0 is None:
                # Before the first label: the span starts there, keep the last second.
                early.append((record.t_ns, record.data))
                while early[0][0] < record.t_ns - _MARGIN_NS:
                    early.popleft()
            elif (
                isinstance(record, PacketRecord)
                and begin - _MARGIN_NS <= record.t_ns < end + _MARGIN_NS
            ):
                chunks.append((record.t_ns, record.data))
    except SimError:
        raise
    except Exception as exc:  # the protocol's SessionError and OS errors, as one line
        msg = f"cannot read {path}: {exc}"
        raise RenderError(msg) from None
    if header is not None and t0 is None:  # no labels at all (a pressure-only import)
        return _unlabelled_span(path, header, start_s, duration_s)
    if header is None or not labels:
        msg = f"{path}: no labelled frames in that span"
        raise RenderError(msg)
    chunks = [c for c in early if c[0] >= begin - _MARGIN_NS] + chunks
    span = _assemble(header, labels, list(stream_pairs(chunks)), t0 or 0)
    return _with_sources(span, sources, begin, end, t0 or 0)


def _unlabelled_span(
    path: str | os.PathLike[str],
    header: SessionHeader,
    start_s: float,
    duration_s: float | None,
) -> Span:
    """A session without labels: the frames themselves give the time axis (no skeleton)."""
    chunks: list[tuple[int, bytes]] = []
    sources: list[SourceFrameRecord] = []
    t0: int | None = None
    try:
        for record in iter_records(path, source_frames=True):
            if isinstance(record, SourceFrameRecord):
                sources.append(record)
            elif isinstance(record, PacketRecord):
                t0 = record.t_ns if t0 is None else t0
                begin = t0 + round(start_s * 1e9)
                end = begin + round(duration_s * 1e9) if duration_s is not None else 2**62
                if record.t_ns >= end + _MARGIN_NS:
                    break
                if record.t_ns >= begin - _MARGIN_NS:
                    chunks.append((record.t_ns, record.data))
    except Exception as exc:  # the protocol's SessionError and OS errors, as one line
        msg = f"cannot read {path}: {exc}"
        raise RenderError(msg) from None
    arrivals = _Arrivals()
    pairs = list(stream_pairs(chunks, FramePath(watch=arrivals)))
    times = arrivals.times
    begin = (t0 or 0) + round(start_s * 1e9)
    end = begin + round(duration_s * 1e9) if duration_s is not None else 2**62
    nothing = np.full((len(KP), 3), np.nan, dtype=np.float32)
    labels = [
        LabelRecord(seq, t_ns, nothing)
        for seq, t_ns in sorted(times.items(), key=lambda item: item[1])
        if begin <= t_ns < end
    ]
    if not labels:
        msg = f"{path}: no frames in that span"
        raise RenderError(msg)
    span = _assemble(header, labels, pairs, t0 or 0)
    return _with_sources(span, sources, begin, end, t0 or 0)


class _Arrivals(FrameWatch):
    """When each frame's seq first arrived: the time axis of a file without labels."""

    def __init__(self) -> None:
        self.times: dict[int, int] = {}

    def frame(self, frame: FootFrame) -> None:
        self.times.setdefault(frame.seq, frame.last_byte_ns)


def _with_sources(
    span: Span, sources: list[SourceFrameRecord], begin: int, end: int, t0: int
) -> Span:
    """``span`` with the imported source frames stored between ``begin`` and ``end``."""
    inside = [r for r in sources if begin - _MARGIN_NS <= r.t_ns < end + _MARGIN_NS]
    if not inside:
        return span
    times_s = np.array([(r.t_ns - t0) / 1e9 for r in inside])
    return replace(span, source_time_s=times_s, source_frames=[r.frames for r in inside])


def _assemble(
    header: SessionHeader, labels: list[LabelRecord], pairs: list[PairedFrame], t0: int
) -> Span:
    index = {label.seq: i for i, label in enumerate(labels)}  # seq is unique within a span
    counts = np.zeros((len(labels), 2, header.rows, header.cols), np.uint16)
    for pair in pairs:
        i = index.get(pair.seqs[0] if pair.seqs[0] >= 0 else pair.seqs[1])
        if i is not None and pair.counts.shape == (header.rows, 2 * header.cols):
            counts[i, 0], counts[i, 1] = np.hsplit(pair.counts, 2)
    return Span(
        time_s=np.array([(label.t_ns - t0) / 1e9 for label in labels]),
        counts=counts,
        keypoints=np.stack([label.keypoints for label in labels]),
        action=np.array([label.action for label in labels]),
        progress=np.array([label.progress for label in labels]),
        header=header,
    )


def _anatomical(counts: np.ndarray) -> np.ndarray:
    """(rows, 2 * cols + 2): left foot mirrored, a gap, right foot as sent."""
    left, right = counts[0][:, ::-1], counts[1]
    gap = np.full((left.shape[0], 2), np.nan)
    return np.hstack([left.astype(float), gap, right.astype(float)])


_SEGMENTS: Final = [(KP[a], KP[b]) for a, b in BONES]


def _draw_skeleton(ax: Any, kp: np.ndarray, view: str) -> None:
    """Side view (x forward, z up) or front view (y left drawn to the right, z up)."""
    horizontal = kp[:, 0] if view == "side" else -kp[:, 1]
    z = kp[:, 2]
    for a, b in _SEGMENTS:
        left_side = "left" in _name(a) or "left" in _name(b)
        ax.plot(
            [horizontal[a], horizontal[b]],
            [z[a], z[b]],
            color="tab:blue" if left_side else "tab:red",
            lw=2,
        )
    ax.scatter(horizontal, z, s=8, color="k", zorder=3)
    ax.axhline(0.0, color="0.6", lw=1)
    ax.set_xlim(-0.75, 0.75)
    ax.set_ylim(-0.05, 1.95)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title("side (facing right)" if view == "side" else "front (viewer's view)", fontsize=7)


def _name(index: int) -> str:
    return next(name for name, i in KP.items() if i == index)


def _action_name(action: int) -> str:
    return ACTIONS[action] if 0 <= action < len(ACTIONS) else "transition"


def _draw_timeline(ax: Any, span: Span, marks: list[float]) -> None:
    t = span.time_s
    load = span.counts.astype(float).sum(axis=(2, 3)) / 1e3
    ax.plot(t, load[:, 0], color="tab:blue", lw=1.5, ls="--", label="left counts (k)")
    ax.plot(t, load[:, 1], color="tab:red", lw=1, label="right counts (k)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("sum of counts / 1000")
    ax.set_xlim(t[0], t[-1] if len(t) > 1 else t[0] + 1)
    twin = ax.twinx()
    twin.plot(t, span.progress, color="k", lw=1.5, label="progress")
    twin.set_ylim(-0.05, 1.05)  # progress is 0..1
    twin.set_ylabel("progress")
    changes = np.flatnonzero(np.diff(span.action, prepend=NO_ACTION - 1))
    for i in changes:
        twin.axvline(t[i], color="0.8", lw=0.8)
        if span.action[i] == NO_ACTION:
            continue  # the stands between actions: unlabelled, so the names do not collide
        # Above the plot (x in data, y in axes units), where no curve or legend is.
        twin.text(t[i], 1.02, _action_name(int(span.action[i])), fontsize=7,
                  transform=twin.get_xaxis_transform(), va="bottom", clip_on=False)  # fmt: skip
    for m in marks:
        ax.axvline(m, color="tab:green", lw=1.2, ls="--")
    # One legend for both axes, below the time axis: it never covers a curve or a label.
    handles = ax.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.32), ncol=3,
              fontsize=6, frameon=False)  # fmt: skip


def _snapshot(fig: Any, grid: Any, span: Span, i: int, wide: bool = False) -> None:
    """Skeleton side and front over both feet, or (``wide``) all three in a row."""
    if wide:
        sub = grid.subgridspec(1, 3, wspace=0.05)
        cells = (sub[0, 0], sub[0, 1], sub[0, 2])
    else:
        sub = grid.subgridspec(2, 2, height_ratios=[1.5, 1.0], hspace=0.2, wspace=0.02)
        cells = (sub[0, 0], sub[0, 1], sub[1, :])
    _draw_skeleton(fig.add_subplot(cells[0]), span.keypoints[i], "side")
    _draw_skeleton(fig.add_subplot(cells[1]), span.keypoints[i], "front")
    ax = fig.add_subplot(cells[2])
    ax.imshow(_anatomical(span.counts[i]), cmap="inferno", vmin=0, vmax=MAX_COUNT * 0.7)
    ax.set_xticks([])
    ax.set_yticks([])
    progress = span.progress[i]
    title = f"t={span.time_s[i]:.2f}s {_action_name(int(span.action[i]))}"
    if np.isfinite(progress):
        title += f" p={progress:.2f}"
    ax.set_title(title + "\nL (mirrored) | R, toes up", fontsize=7)


def render_png(span: Span, out: str | os.PathLike[str]) -> Path:
    """Snapshots across the span (skeleton side + front, both feet) and a timeline."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(span.time_s)
    picks = np.unique(np.linspace(0, n - 1, min(_SNAPSHOTS, n)).round().astype(int))
    if span.source_frames:  # imported: snapshots where a source frame was kept
        picks = _picks_at_sources(span, picks)
    rows = 3 if span.source_frames else 2
    fig = plt.figure(figsize=(3.0 * len(picks), 7.0 + 2.2 * (rows - 2)), dpi=100)
    fig.subplots_adjust(left=0.06, right=0.94, top=0.93, bottom=0.1)
    ratios = [3.0, 1.2, 1.0] if rows == 3 else [3.0, 1.0]
    grid = fig.add_gridspec(rows, len(picks), height_ratios=ratios, hspace=0.25)
    for col, i in enumerate(picks):
        _snapshot(fig, grid[0, col], span, int(i))
        if span.source_frames:
            _draw_source(fig.add_subplot(grid[1, col]), span, int(i))
    timeline = fig.add_subplot(grid[rows - 1, :])
    _draw_timeline(timeline, span, [float(span.time_s[i]) for i in picks])
    scene = span.header.scene or {}
    fig.suptitle(f"{Path(out).stem}: {scene.get('name', span.header.source)}", fontsize=9)
    path = Path(out)
    fig.savefig(path)
    plt.close(fig)
    return path


def _nearest_source(span: Span, i: int) -> int:
    return int(np.argmin(np.abs(span.source_time_s - span.time_s[i])))


def _picks_at_sources(span: Span, picks: np.ndarray) -> np.ndarray:
    """Move each snapshot to the labelled frame nearest a kept source frame."""
    inside = span.source_time_s[
        (span.source_time_s >= span.time_s[0]) & (span.source_time_s <= span.time_s[-1])
    ]
    if not inside.size:
        return picks
    wanted = inside[np.unique(np.linspace(0, inside.size - 1, picks.size).round().astype(int))]
    return np.unique([int(np.argmin(np.abs(span.time_s - t))) for t in wanted])


def _draw_source(ax: Any, span: Span, i: int) -> None:
    """The source frame nearest frame i, both feet as the other insole stored them."""
    k = _nearest_source(span, i)
    frames = span.source_frames[k]
    gap = np.full((frames.shape[1], 1), np.nan)
    ax.imshow(np.hstack([frames[0], gap, frames[1]]), cmap="inferno", vmin=0)
    ax.set_xticks([])
    ax.set_yticks([])
    rows, cols = frames.shape[1:]
    ax.set_title(
        f"source t={span.source_time_s[k]:.2f}s, {rows} x {cols}\nL | R as stored", fontsize=7
    )


def render_gif(span: Span, out: str | os.PathLike[str], fps: float = _GIF_FPS) -> Path:
    """An animation of the span: skeleton, both feet and the timeline cursor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    rate = span.header.rate_hz or 16.0
    step = max(1, round(rate / fps))
    frames = list(range(0, len(span.time_s), step))
    fig = plt.figure(figsize=(7.2, 4.8), dpi=72)

    def draw(k: int) -> list[Any]:
        fig.clear()
        fig.subplots_adjust(left=0.08, right=0.9, top=0.95, bottom=0.1)
        g = fig.add_gridspec(2, 1, height_ratios=[2.2, 1.0], hspace=0.25)
        _snapshot(fig, g[0, 0], span, k, wide=True)
        _draw_timeline(fig.add_subplot(g[1, 0]), span, [float(span.time_s[k])])
        return []

    anim = FuncAnimation(fig, draw, frames=frames, blit=False)
    path = Path(out)
    anim.save(str(path), writer=PillowWriter(fps=max(1, round(rate / step))))
    plt.close(fig)
    return path
