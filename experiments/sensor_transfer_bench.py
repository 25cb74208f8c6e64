"""What ``--sensor-transfer`` costs the data loader, per training window.

    python experiments/sensor_transfer_bench.py [SESSIONS...] [--batches 40] [--stride 16]

Builds the same batches as ``scotti train`` (``plan_epoch`` + ``batch_tensors``:
slicing, the shift, crosstalk 0.03 as the shipped recipe) without a model, once
without the augmentation and once with every chunk read through a drawn foreign
insole (``--sensor-transfer 1``), and prints milliseconds per window of each,
and of the drawn sensors by geometry. ``--sensor-transfer P`` costs P times the
difference. One thread, as a ``--workers 1`` prefetch thread builds them; timed on
a second pass over the batches, once the cell geometries and time matrices a run
builds in its first few hundred chunks are cached.
Default sessions: data/insole_transfer/people (experiments/insole_transfer.py
simulates them).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

from common import ROOT, ExperimentError

DEFAULT_SESSIONS = ROOT / "data" / "insole_transfer" / "people"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("sessions", nargs="*", type=Path, default=[DEFAULT_SESSIONS])
    p.add_argument("--batches", type=int, default=40, help="batches timed per setting")
    p.add_argument("--stride", type=int, default=16, help="as the shipped recipe")
    p.add_argument("--cache", type=Path, default=ROOT / "data" / "insole_transfer" / "cache")
    args = p.parse_args(argv)
    try:
        import torch
        from scotti.export.data import find_sessions, load_session
        from scotti.export.epochs import batch_tensors, plan_epoch
        from scotti.export.sensor_transfer import cell_layouts
        from scotti.export.train import TrainOptions
        from scotti.export.windows import WindowDataset

        torch.set_num_threads(1)
        paths = find_sessions(args.sessions)
        if not paths:
            msg = f"no session files in {', '.join(map(str, args.sessions))}"
            raise ExperimentError(msg)
        data = WindowDataset([load_session(path, args.cache) for path in paths])
        recipe = TrainOptions(stride=args.stride, max_crosstalk=0.03)
        for share in (0.0, 1.0):
            opts = replace(recipe, sensor_transfer=share)
            batches = plan_epoch(data, opts, epoch=0)[: args.batches]
            for batch in batches:  # warm: the geometries and time matrices a run builds once
                batch_tensors(data, batch)
            by_kind: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0])
            started = time.perf_counter()
            windows = 0
            for batch in batches:
                for planned in batch:
                    t0 = time.perf_counter()
                    batch_tensors(data, [planned])
                    kind = "ours" if planned.sensor is None else _kind(planned.sensor)
                    by_kind[kind][0] += time.perf_counter() - t0
                    by_kind[kind][1] += planned.chunk.count
                windows += sum(planned.chunk.count for planned in batch)
            ms = 1e3 * (time.perf_counter() - started) / windows
            print(
                f"--sensor-transfer {share:g}: {ms:.3f} ms per window "
                f"({windows} windows, stride {args.stride}, chunk {opts.chunk})"
            )
            for kind, (seconds, n) in sorted(by_kind.items()):
                print(f"  {kind}: {1e3 * seconds / n:.3f} ms per window ({n:.0f} windows)")
        layouts = cell_layouts()
        print(f"cell layouts drawn: {', '.join(layouts) if layouts else 'none (grids only)'}")
    except ExperimentError as exc:
        print(f"sensor_transfer_bench: {exc}", file=sys.stderr)
        return 2
    return 0


def _kind(sensor: object) -> str:
    layout = getattr(sensor, "layout", None)
    if layout is not None:
        return f"cells {layout}"
    cells = int(getattr(sensor, "rows", 0)) * int(getattr(sensor, "cols", 0))
    return "grid, more cells than ours" if cells > 32 * 22 else "grid, fewer cells than ours"


if __name__ == "__main__":
    sys.exit(main())
