"""Lab Streaming Layer outlets: what a biomechanics lab's LabRecorder picks up.

Four streams per device, 16 Hz, float32 unless said, named ``<device> <what>``
with the source id ``scotti/<device>/<what>`` (the device's id as in its MQTT
topics) so that LabRecorder tells the devices apart and finds each stream
again after a restart:

| stream type | channels | labels |
|---|---|---|
| ``MoCap`` (pose) | 57 | ``nose_x``, ``nose_y``, ``nose_z``, ... metres, pose frame |
| ``Classifier`` (action) | one per action | the action names, probabilities |
| ``Progress`` | 2 | ``progress`` (NaN while there is none), ``repetition`` |
| ``Pressure`` | 2 x 704, int16 | ``left_r00c00`` ... raw counts, row-major per foot |

Each sample is stamped with its frame's time in LSL's clock: the host
monotonic time the frame's last byte arrived (liblsl's ``local_clock`` is the
same steady clock), so LabRecorder lines it up with every other device in
the room. pylsl's wheels bundle liblsl (1.18 in pylsl 1.18.6); nothing to
install from Debian.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np
import pylsl
from scotti.daemon.frames.pipeline import Prediction
from scotti.daemon.mqtt.schemas import Status
from scotti.models.contract import ACTIONS, FRAME_COLS, FRAME_RATE_HZ, FRAME_ROWS, KEYPOINTS

POSE_LABELS: Final = tuple(f"{k}_{axis}" for k in KEYPOINTS for axis in "xyz")
PROGRESS_LABELS: Final = ("progress", "repetition")
PRESSURE_LABELS: Final = tuple(
    f"{foot}_r{r:02d}c{c:02d}"
    for foot in ("left", "right")
    for r in range(FRAME_ROWS)
    for c in range(FRAME_COLS)
)


def _outlet(
    device: str, what: str, kind: str, labels: tuple[str, ...], unit: str, fmt: int
) -> pylsl.StreamOutlet:
    info = pylsl.StreamInfo(
        name=f"{device} {what}",
        type=kind,
        channel_count=len(labels),
        nominal_srate=FRAME_RATE_HZ,
        channel_format=fmt,
        source_id=f"scotti/{device}/{what}",
    )
    info.set_channel_labels(list(labels))
    info.set_channel_units([unit] * len(labels))
    return pylsl.StreamOutlet(info)


class LslOutlets:
    """The four outlets; ``push`` one prediction into all of them."""

    def __init__(self, device: str) -> None:
        f32, i16 = pylsl.cf_float32, pylsl.cf_int16
        self.pose = _outlet(device, "pose", "MoCap", POSE_LABELS, "metres", f32)
        self.action = _outlet(device, "action", "Classifier", ACTIONS, "probability", f32)
        self.progress = _outlet(device, "progress", "Progress", PROGRESS_LABELS, "fraction", f32)
        self.pressure = _outlet(device, "pressure", "Pressure", PRESSURE_LABELS, "counts", i16)

    def push(self, p: Prediction) -> None:
        stamp = (p.last_byte_mono_ns or p.host_mono_ns) / 1e9  # LSL time = steady clock, s
        progress = _or_nan(p.progress)
        self.pose.push_sample(np.asarray(p.pose, dtype=np.float32).reshape(-1), stamp)
        self.action.push_sample(np.asarray(p.action_probs, dtype=np.float32), stamp)
        self.progress.push_sample([progress, float(p.repetition)], stamp)
        counts = np.asarray(p.counts, dtype=np.int16)  # 12-bit counts fit
        feet = np.concatenate([counts[:, :FRAME_COLS].reshape(-1), counts[:, FRAME_COLS:].ravel()])
        self.pressure.push_sample(feet, stamp)


def _or_nan(progress: float | None) -> float:
    """Progress as a sample: NaN while there is none (null in MQTT, e.g. standing)."""
    return float("nan") if progress is None else float(progress)


class LslOutput:
    """Four outlets per device, each named after its device: LabRecorder lists a
    dozen pairs as a dozen groups of four streams and records any of them."""

    name = "lsl"

    def __init__(self, devices: Sequence[str]) -> None:
        self.outlets = {device: LslOutlets(device) for device in devices}

    def __str__(self) -> str:
        names = ", ".join(f"'{d} pose|action|progress|pressure'" for d in self.outlets)
        return f"lsl: {4 * len(self.outlets)} outlets named {names}"

    def prediction(self, device: str, p: Prediction, latency_ms: float) -> None:
        self.outlets[device].push(p)

    def status(self, device: str, status: Status) -> None:
        pass  # LSL streams carry samples; a silent stream is LabRecorder's sign of trouble

    async def close(self) -> None:
        self.outlets.clear()  # the outlets close (and leave the network) when dropped
