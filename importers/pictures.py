"""The pictures of importers/IMPORT.md: ``python -m scotti.importers.pictures [-o importers/img]``.

Each is drawn from the importers' own functions on a small synthetic
recording, so the pictures show what the code does:

- grid.png: a 16 x 8 insole stored toes-last and mirrored, turned into our
  orientation, and remapped by shared area onto 32 x 22 with our outline;
- time.png: a 50 Hz and a 10 Hz signal resampled to 16 Hz, and a gap that
  splits the session;
- pose.png: a camera frame with y down, and the same pose in the contract's
  pose frame;
- counts.png: the count scale (models/insole.py) with a counts-per-kPa and
  a body-mass calibration;
- layout-<name>.png: each discrete-cell layout (importers/layouts.py) on our
  grid, left foot: which cell feeds each taxel, and a load seen through the
  cells (``--layouts`` draws only these).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scotti.importers.grid import GridMapper, Orientation
from scotti.importers.layouts import CellRenderer, known_layouts, layout
from scotti.importers.pose import STANDING_POSE, pose_frame, up_rotation
from scotti.importers.timebase import PERIOD_S, box_average, plan_timeline
from scotti.models.contract import BONES, KEYPOINTS, KP
from scotti.models.insole import INSOLE_WIDTH_RATIO, counts_from_kpa, insole_mask


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _example_foot(rows: int, cols: int) -> np.ndarray:
    """A foot-like load in our orientation (toes row 0, medial column 0), kPa."""
    r = (np.arange(rows) + 0.5)[:, None] / rows
    c = (np.arange(cols) + 0.5)[None, :] / cols
    heel = 160 * np.exp(-0.5 * (((r - 0.85) / 0.08) ** 2 + ((c - 0.5) / 0.2) ** 2))
    ball = 140 * np.exp(-0.5 * (((r - 0.3) / 0.07) ** 2 + ((c - 0.35) / 0.25) ** 2))
    hallux = 90 * np.exp(-0.5 * (((r - 0.08) / 0.05) ** 2 + ((c - 0.2) / 0.1) ** 2))
    return np.asarray(heel + ball + hallux)


def draw_grid(path: Path) -> None:
    plt = _plt()
    ours = _example_foot(16, 8)
    stored = ours[::-1, ::-1]  # the other insole: toes last, medial last
    oriented = Orientation(toes_first_row=False, medial_first_col=False).apply(stored[None])[0]
    mapped = GridMapper(16, 8)(oriented[None])[0]
    fig, axes = plt.subplots(1, 3, figsize=(9, 5), dpi=100)
    vmax = float(ours.max())
    panels = [
        (stored, "as stored: 16 x 8\ntoes = last_row, medial = last_col"),
        (oriented, "our orientation\ntoes row 0, medial column 0"),
        (mapped, "remapped by shared area\n32 x 22, outside our outline = 0"),
    ]
    for ax, (image, title) in zip(axes, panels, strict=True):
        ax.imshow(image, cmap="inferno", vmin=0, vmax=vmax, extent=(0, 1, 1, 0), aspect=1.6)
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    for k in range(9):  # the source cells over our grid
        axes[2].axvline(k / 8, color="cyan", lw=0.5)
    for k in range(17):
        axes[2].axhline(k / 16, color="cyan", lw=0.5)
    outline = insole_mask().astype(float)
    axes[2].contour(
        np.linspace(0, 1, 22), np.linspace(0, 1, 32), outline, levels=[0.5], colors="white"
    )
    axes[2].set_xlabel("cyan: the 16 x 8 source cells; white: our outline", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def draw_time(path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), dpi=100)

    def signal(t: np.ndarray) -> np.ndarray:
        return np.asarray(np.sin(2 * np.pi * 1.1 * t) + 0.4 * np.sign(np.sin(2 * np.pi * 3.3 * t)))

    for rate, colour in ((50.0, "tab:blue"), (10.0, "tab:orange")):
        t = np.arange(0, 2.0, 1 / rate)
        tl = plan_timeline(t)
        out = box_average(t, signal(t)[:, None], tl.times)[:, 0]
        axes[0].plot(t, signal(t), ".", color=colour, ms=3, label=f"source {rate:g} Hz")
        axes[0].step(
            tl.times, out, where="mid", color=colour, lw=1.2, label=f"{rate:g} Hz -> 16 Hz"
        )
    axes[0].set_title(f"mean of the source over each frame's period ({PERIOD_S * 1000:.1f} ms)")
    axes[0].legend(fontsize=7, ncol=2)
    t = np.r_[np.arange(0, 1.5, 0.02), np.arange(3.0, 4.0, 0.02)]
    tl = plan_timeline(t)
    axes[1].plot(t, np.zeros_like(t), "|", color="0.5", label="source frames (50 Hz)")
    for seg in range(len(tl.source_ranges)):
        rows = tl.segment == seg
        axes[1].plot(tl.times[rows], np.full(rows.sum(), 1.0), "|", ms=10, label=f"segment {seg}")
        first = np.flatnonzero(rows)[0]
        axes[1].annotate(f"seq {tl.seq[first]}", (tl.times[first], 1.0), (0, 8), fontsize=7,
                         textcoords="offset points")  # fmt: skip
    axes[1].set_ylim(-0.5, 1.8)
    axes[1].set_yticks([])
    axes[1].set_xlabel("source clock (s)")
    axes[1].set_title("a gap over 1 s (the contract's restart gap) splits: sequence numbers jump")
    axes[1].legend(fontsize=7, loc="center")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def draw_pose(path: Path) -> None:
    plt = _plt()
    pose = np.array([STANDING_POSE[name] for name in KEYPOINTS])
    heading = 0.9
    c, s = np.cos(heading), np.sin(heading)
    world = pose.copy()
    world[:, 0] = c * pose[:, 0] - s * pose[:, 1] + 0.4
    world[:, 1] = s * pose[:, 0] + c * pose[:, 1] - 0.3
    camera = np.stack([-world[:, 1], 1.2 - world[:, 2], world[:, 0] + 3.0], axis=1)
    back = (camera @ up_rotation(np.array([0.0, -1.0, 0.0])).T)[None]
    back[..., 2] -= back[0, [KP["left_heel"], KP["right_heel"]], 2].min()
    ours = pose_frame(back)[0]
    fig, axes = plt.subplots(1, 3, figsize=(10, 4.2), dpi=100)
    above = "pose frame from above\nx facing, y left, origin mid-hip"
    views = [
        (axes[0], camera[:, 0], camera[:, 1], "camera frame: x right, y DOWN\n(front view)", True),
        (axes[1], ours[:, 0], ours[:, 1], above, False),
        (axes[2], ours[:, 0], ours[:, 2], "pose frame from the side\nz up, floor at 0", False),
    ]
    for ax, h, v, title, flip in views:
        for a, b in BONES:
            colour = "tab:blue" if "left" in a or "left" in b else "tab:red"
            ax.plot([h[KP[a]], h[KP[b]]], [v[KP[a]], v[KP[b]]], color=colour, lw=2)
        ax.scatter(h, v, s=6, color="k", zorder=3)
        ax.set_title(title, fontsize=9)
        ax.set_aspect("equal")
        if flip:
            ax.invert_yaxis()
    axes[1].annotate("", (0.35, 0), (0, 0), arrowprops={"arrowstyle": "->", "color": "green"})
    axes[1].text(0.2, 0.03, "facing", color="green", fontsize=8)
    axes[2].axhline(0.0, color="0.6", lw=1)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def draw_counts(path: Path) -> None:
    plt = _plt()
    kpa = np.linspace(0, 800, 400)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8), dpi=100)
    axes[0].plot(kpa, counts_from_kpa(kpa), color="k")
    axes[0].set_xlabel("pressure on a taxel (kPa)")
    axes[0].set_ylabel("counts (12-bit)")
    axes[0].set_title(
        "our count scale: 4095 q^0.8 / (q^0.8 + 180^0.8), q = p - 20 kPa, rail 3800", fontsize=9
    )
    units = np.linspace(0, 1600, 400)
    for per_kpa in (2.0, 5.0):
        axes[1].plot(
            units, counts_from_kpa(units / per_kpa), label=f"per_kpa: {per_kpa:g} units/kPa"
        )
    axes[1].plot(units, np.minimum(units, 4095), "--", label="counts: gain 1")
    axes[1].set_xlabel("the other sensor's value")
    axes[1].set_title("another sensor onto it", fontsize=9)
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def draw_layout(path: Path, name: str) -> None:
    plt = _plt()
    cells = layout(name).for_foot("left")
    render = CellRenderer(cells)
    top = render.membership.argmax(axis=1).reshape(32, 22)
    live = insole_mask()
    # Neighbouring cells get far-apart hues: golden-ratio steps around the circle.
    hue = (np.arange(cells.cells) * 0.618034) % 1.0
    colours = plt.get_cmap("hsv")(hue)[:, :3] * 0.55 + 0.45
    rgb = np.where(live[..., None], colours[top], 1.0)
    example = _example_foot(32, 22) * live
    seen = render(render.cell_means(example[None]))[0]
    fig, axes = plt.subplots(1, 3, figsize=(10.5, 5.6), dpi=100)
    axes[0].imshow(rgb, extent=(0, 22, 32, 0), interpolation="nearest")
    if cells.outlines is not None:
        for poly in cells.outlines:
            xy = np.r_[poly, poly[:1]]
            axes[0].plot(xy[:, 1] * 22, xy[:, 0] * 32, color="k", lw=0.4)
    small = 4.5 if cells.cells > 30 else 8
    for i, (a, c) in enumerate(cells.centres):
        axes[0].text(c * 22, a * 32, str(i + 1), fontsize=small, ha="center", va="center")
    kind = "point sensors, tiles" if cells.point_sensors else "tiles" if cells.tiled else "outlines"
    axes[0].set_title(f"{name}: {cells.cells} cells ({kind})\neach taxel coloured by its cell",
                      fontsize=9)  # fmt: skip
    vmax = float(example.max())
    for ax, image, title in (
        (axes[1], example, "a load on our grid (kPa)"),
        (axes[2], seen, "seen through the cells, rendered back\n(cell means, then the renderer)"),
    ):
        ax.imshow(np.where(live, image, np.nan), cmap="inferno", vmin=0, vmax=vmax,
                  extent=(0, 22, 32, 0), interpolation="nearest")  # fmt: skip
        ax.set_title(title, fontsize=9)
    force = [float(x.sum() * cells.taxel_area_mm2 * 1e-3) for x in (example, seen)]
    axes[2].set_xlabel(f"force {force[0]:.0f} N on the left, {force[1]:.0f} N here", fontsize=8)
    for ax in axes:
        ax.contour(np.arange(22) + 0.5, np.arange(32) + 0.5, live.astype(float), levels=[0.5],
                   colors="0.3", linewidths=0.8)  # fmt: skip
        ax.set_xlim(0, 22)
        ax.set_ylim(32, 0)
        ax.set_xticks([0, 11, 22], ["medial", "", "lateral"], fontsize=7)
        ax.set_yticks([0, 16, 32], ["toes", "", "heel"], fontsize=7)
        ax.set_aspect(22 / (32 * INSOLE_WIDTH_RATIO))  # a taxel as long and wide as on the sole
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scotti.importers.pictures")
    parser.add_argument("-o", "--output", type=Path, default=Path("importers/img"))
    parser.add_argument("--layouts", action="store_true", help="only the cell layouts' pictures")
    args = parser.parse_args(argv)
    args.output.mkdir(parents=True, exist_ok=True)
    pictures = [] if args.layouts else [
        ("grid", draw_grid),
        ("time", draw_time),
        ("pose", draw_pose),
        ("counts", draw_counts),
    ]  # fmt: skip
    for name, draw in pictures:
        draw(args.output / f"{name}.png")
        print(args.output / f"{name}.png")
    for name in known_layouts():
        draw_layout(args.output / f"layout-{name}.png", name)
        print(args.output / f"layout-{name}.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
