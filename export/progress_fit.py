"""The progress calibration fitted at export (``scotti export --calibrate``).

The same held-out subjects that set the unfamiliar score's threshold
(export/ood_calibration.py) give the progress calibration
(models/progress_calibration.py): their usable windows, thinned evenly to at
most ``Calibration.progress_windows``, go through the exported window graph
with the progress head's output as it is, and the map is fitted from that
output to the label of the time each window predicts (the frame after its
last). ``scotti calibrate`` does the same later, on any held-out sessions,
through the daemon's streaming path.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scotti.export.data import SessionArrays
from scotti.export.ood_calibration import Calibration
from scotti.export.windows import WindowDataset
from scotti.models.progress_calibration import ProgressCalibration, fit
from scotti.models.runtime import ScottiRuntime

BATCH = 64  # windows per run of the window graph


def fit_progress(
    window_graph: Path,
    held_out: Sequence[SessionArrays],
    request: Calibration,
    threads: int = 1,
) -> ProgressCalibration | None:
    """The calibration of the graph's progress on the held-out sessions; None when
    asked for none (``progress_windows`` 0) or no action had enough windows."""
    if request.progress_windows <= 0 or not held_out:
        return None
    graph = ScottiRuntime(window_graph, threads, calibrate_progress=False)
    data = WindowDataset(list(held_out), graph.window)
    stride = max(1, -(-data.count() // request.progress_windows))
    output, label, action = [], [], []
    for i, session in enumerate(held_out):
        starts = data.starts(i, stride=stride)
        for k in range(0, len(starts), BATCH):
            chunk = starts[k : k + BATCH]
            windows = np.stack([session.frames[t : t + graph.window] for t in chunk])
            result = graph.run_windows(windows.astype(np.float32), batch_size=len(chunk))
            output.append(result.progress)
            action.append(np.argmax(result.action_logits, axis=-1))
            label.append(session.progress[chunk + graph.window])  # the time it predicts
    if not output:
        return None
    p, t, a = np.concatenate(output), np.concatenate(label), np.concatenate(action)
    calibration = fit(p, t, a, min_frames=request.progress_min_windows)
    if not calibration.knots:
        return None
    calibration.summary.update(fitted_on=sorted({s.subject for s in held_out}), windows=int(p.size))
    return calibration
