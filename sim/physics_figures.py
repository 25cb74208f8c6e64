"""The simulator's physics in numbers: what a force plate would say about a motion.

:func:`measure` takes a motion (built at ``scene.PHYSICS_OVERSAMPLE``, so
that forces come from 128 Hz kinematics), computes its foot loads and returns
one figure per physical claim, each next to the range people show:

=========================  ========================================  ==================
figure                     what                                      people
=========================  ========================================  ==================
walking peaks / valley     per foot, median over complete stances    1.1-1.3 / 0.7-0.8
                           (first-half max, second-half max, min     BW (Perry 1992;
                           between them), body weights               Winter 2009)
COP onset / offset         cop_u (0 heel .. 1 toes) at a stance's    heel -> toe
                           first and last loaded sample, per gait    forwards, toe
                                                                     first backwards
side walking COP           share of the whole-body COP's sideways    most of it (the
                           path that goes the way the person         first shift, to
                           travels                                   unload the leading
                                                                     foot, goes back)
jump landing peak          both feet, median over landings, BW       2.5-4 (Bobbert
                                                                     1987; McNitt-Gray
                                                                     1993)
jump flight load           largest load with both feet off, N        0
jump L/R                   median touch-down gap (ms) and load       not 0
                           split difference of the landing peaks
step-up lead peak          the foot on the step until the other      1.3-1.5 BW
                           joins it, median over steps, BW           (Stacoff 2005)
squat COP vs depth         correlation of mean cop_u with hip drop   < 0 (to the heels)
standing COM offset        COM in front of the ankles, metres        0.04-0.06
                                                                     (Winter 1995)
=========================  ========================================  ==================

A figure is NaN when the motion has no such action. Pure: no files, no
printing; ``scotti sim realism`` (the lead's) formats them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt
from scotti.models.contract import ACTIONS, KP, STANDING
from scotti.sim.loads import CONTACT_FULL_M, FootLoads, G, foot_loads
from scotti.sim.motion import Motion
from scotti.sim.skeleton import axes

Array = npt.NDArray[np.float64]

# A stance: contact at least this much for at least MIN_STANCE_S.
_STANCE_CONTACT = 0.5
_MIN_STANCE_S = 0.2
# A landing's peak is looked for this long after touch-down.
_LANDING_WINDOW_S = 0.15
# Flight: both feet off for at least this long.
_MIN_FLIGHT_S = 0.05
# A stance sample counts as loaded above this share of body weight.
_LOADED_BW = 0.05

NAN = float("nan")


@dataclass(frozen=True)
class PhysicsFigures:
    """One number per claim (NaN: not in this motion); see the module table."""

    rate_hz: float
    walking_first_peak_bw: float = NAN
    walking_second_peak_bw: float = NAN
    walking_valley_bw: float = NAN
    walking_cop_onset_u: float = NAN
    walking_cop_offset_u: float = NAN
    backward_cop_onset_u: float = NAN
    backward_cop_offset_u: float = NAN
    side_cop_with_travel: float = NAN
    jump_landing_peak_bw: float = NAN
    jump_flight_max_n: float = NAN
    jump_touchdown_gap_ms: float = NAN
    jump_split_difference: float = NAN
    step_up_lead_peak_bw: float = NAN
    squat_cop_depth_correlation: float = NAN
    standing_com_ahead_m: float = NAN

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


def measure(motion: Motion, loads: FootLoads | None = None) -> PhysicsFigures:
    """Figures of ``motion`` (loads computed at its rate unless given)."""
    if loads is None:
        loads = foot_loads(
            motion.world, motion.com, motion.rate_hz, motion.subject.mass_kg, motion.ground_z
        )
    bw = motion.subject.mass_kg * G
    figures: dict[str, float] = {}
    walk = _runs_of(motion, "walking")
    if walk:
        first, second, valley = _double_hump(motion, loads, walk, bw)
        figures |= {
            "walking_first_peak_bw": first,
            "walking_second_peak_bw": second,
            "walking_valley_bw": valley,
        }
        onset, offset = _cop_roll(motion, loads, walk, bw)
        figures |= {"walking_cop_onset_u": onset, "walking_cop_offset_u": offset}
    back = _runs_of(motion, "backward_walking")
    if back:
        onset, offset = _cop_roll(motion, loads, back, bw)
        figures |= {"backward_cop_onset_u": onset, "backward_cop_offset_u": offset}
    side = _runs_of(motion, "side_walking")
    if side:
        figures["side_cop_with_travel"] = _side_travel(motion, loads, side)
    jumps = _runs_of(motion, "jump")
    if jumps:
        figures |= _jump_figures(motion, loads, jumps, bw)
    steps = _runs_of(motion, "step_up")
    if steps:
        figures["step_up_lead_peak_bw"] = _step_up_peak(motion, loads, steps, bw)
    squats = _runs_of(motion, "squat")
    if squats:
        figures["squat_cop_depth_correlation"] = _squat_cop(motion, loads, squats)
    figures["standing_com_ahead_m"] = _standing_offset(motion)
    return PhysicsFigures(rate_hz=motion.rate_hz, **figures)


# --- helpers ------------------------------------------------------------------


def _runs(mask: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[start, end) of each run of True."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _runs_of(motion: Motion, action: str) -> list[tuple[int, int]]:
    return _runs(motion.action == ACTIONS.index(action))


def _stances(
    motion: Motion, loads: FootLoads, runs: list[tuple[int, int]]
) -> list[tuple[int, int, int]]:
    """(foot, start, end) of every stance wholly inside one of ``runs``."""
    out: list[tuple[int, int, int]] = []
    least = round(_MIN_STANCE_S * motion.rate_hz)
    for foot in (0, 1):
        on = loads.contact[:, foot] >= _STANCE_CONTACT
        for start, end in _runs(on):
            inside = any(a < start and end < b for a, b in runs)
            if inside and end - start >= least:
                out.append((foot, start, end))
    return out


def _double_hump(
    motion: Motion, loads: FootLoads, runs: list[tuple[int, int]], bw: float
) -> tuple[float, float, float]:
    firsts, seconds, valleys = [], [], []
    for foot, start, end in _stances(motion, loads, runs):
        f = loads.load_n[start:end, foot] / bw
        mid = len(f) // 2
        i1 = int(np.argmax(f[:mid]))
        i2 = mid + int(np.argmax(f[mid:]))
        firsts.append(f[i1])
        seconds.append(f[i2])
        valleys.append(f[i1 : i2 + 1].min())
    if not firsts:
        return NAN, NAN, NAN
    return float(np.median(firsts)), float(np.median(seconds)), float(np.median(valleys))


def _cop_roll(
    motion: Motion, loads: FootLoads, runs: list[tuple[int, int]], bw: float
) -> tuple[float, float]:
    onsets, offsets = [], []
    for foot, start, end in _stances(motion, loads, runs):
        loaded = np.flatnonzero(loads.load_n[start:end, foot] > _LOADED_BW * bw)
        if loaded.size:
            onsets.append(loads.cop_u[start + loaded[0], foot])
            offsets.append(loads.cop_u[start + loaded[-1], foot])
    if not onsets:
        return NAN, NAN
    return float(np.median(onsets)), float(np.median(offsets))


def cop_world(motion: Motion, loads: FootLoads) -> Array:
    """(N, 2, 2) each foot's COP on the floor, world x, y (from heel, toes and cop_u)."""
    heel = motion.world[:, [KP["left_heel"], KP["right_heel"]], :2]
    toe = 0.5 * (
        motion.world[:, [KP["left_big_toe"], KP["right_big_toe"]], :2]
        + motion.world[:, [KP["left_small_toe"], KP["right_small_toe"]], :2]
    )
    return np.asarray(heel + (toe - heel) * loads.cop_u[..., None], dtype=np.float64)


def _side_travel(motion: Motion, loads: FootLoads, runs: list[tuple[int, int]]) -> float:
    cop = cop_world(motion, loads)
    shares = []
    for start, end in runs:
        w = loads.load_n[start:end]
        total = w.sum(axis=1)
        ok = total > 0
        whole = (w[ok, :, None] * cop[start:end][ok]).sum(axis=1) / total[ok, None]
        _, left = axes(float(motion.heading[start]))
        lateral = whole @ left[:2]
        hips = motion.world[start:end, [KP["left_hip"], KP["right_hip"]]]
        pelvis = hips.mean(axis=1)
        travel = float((pelvis[-1, :2] - pelvis[0, :2]) @ left[:2])
        if abs(travel) < 1e-3 or lateral.size < 2:
            continue
        moved = np.diff(lateral) * np.sign(travel)
        shares.append(float(moved[moved > 0].sum() / max(np.abs(moved).sum(), 1e-12)))
    return float(np.mean(shares)) if shares else NAN


def _jump_figures(
    motion: Motion, loads: FootLoads, runs: list[tuple[int, int]], bw: float
) -> dict[str, float]:
    rate = motion.rate_hz
    airborne = (loads.contact == 0).all(axis=1)
    peaks, flight_max, gaps, splits = [], 0.0, [], []
    window = round(_LANDING_WINDOW_S * rate)
    # The action label runs crouch to crouch; flights lie inside.
    for a, b in runs:
        for start, end in _runs(airborne[a:b]):
            if end - start < _MIN_FLIGHT_S * rate:
                continue
            start, end = a + start, a + end
            flight_max = max(flight_max, float(loads.load_n[start:end].max()))
            after = slice(end, min(len(airborne), end + window))
            peaks.append(float(loads.load_n[after].sum(axis=1).max()) / bw)
            lr = loads.load_n[after].max(axis=0)
            splits.append(float(abs(lr[0] - lr[1]) / max(lr.sum(), 1e-9)))
            touch = [end + int(np.argmax(loads.contact[after, f] > 0)) for f in (0, 1)]
            gaps.append(1000.0 * abs(touch[0] - touch[1]) / rate)
    if not peaks:
        return {}
    return {
        "jump_landing_peak_bw": float(np.median(peaks)),
        "jump_flight_max_n": flight_max,
        "jump_touchdown_gap_ms": float(np.median(gaps)),
        "jump_split_difference": float(np.median(splits)),
    }


def _step_up_peak(
    motion: Motion, loads: FootLoads, runs: list[tuple[int, int]], bw: float
) -> float:
    if motion.ground_z is None:
        return NAN
    heel_z = motion.world[:, [KP["left_heel"], KP["right_heel"]], 2]
    on_step = (motion.ground_z > 0) & (heel_z - motion.ground_z < CONTACT_FULL_M + 0.05)
    loaded = on_step & (loads.contact > 0)
    peaks = []
    for a, b in runs:
        for foot in (0, 1):
            for start, end in _runs(loaded[a:b, foot]):
                start, end = a + start, a + end
                # Until the other foot is on the step too: the leading leg's push.
                other = np.flatnonzero(loaded[start:end, 1 - foot])
                stop = start + int(other[0]) if other.size else end
                if stop > start and not loaded[start - 1, 1 - foot]:
                    peaks.append(float(loads.load_n[start:stop, foot].max()) / bw)
    return float(np.median(peaks)) if peaks else NAN


def _squat_cop(motion: Motion, loads: FootLoads, runs: list[tuple[int, int]]) -> float:
    corr = []
    for a, b in runs:
        hip = 0.5 * (motion.world[a:b, KP["left_hip"], 2] + motion.world[a:b, KP["right_hip"], 2])
        drop = hip.max() - hip
        cop = loads.cop_u[a:b].mean(axis=1)
        if drop.std() > 0 and cop.std() > 0:
            corr.append(float(np.corrcoef(drop, cop)[0, 1]))
    return float(np.mean(corr)) if corr else NAN


def _standing_offset(motion: Motion) -> float:
    """COM ahead of the ankles' midpoint along the heading, over the quiet stands."""
    still = motion.action == STANDING
    ankles = 0.5 * (motion.world[:, KP["left_ankle"]] + motion.world[:, KP["right_ankle"]])
    feet_down = (motion.world[:, [KP["left_heel"], KP["right_heel"]], 2] < 0.005).all(axis=1)
    speed = np.r_[0.0, np.linalg.norm(np.diff(ankles, axis=0), axis=1) * motion.rate_hz]
    quiet = still & feet_down & (speed < 0.01)
    if not quiet.any():
        return NAN
    forward, _ = axes(motion.heading[quiet])
    ahead = ((motion.com[quiet, :2] - ankles[quiet, :2]) * forward[:, :2]).sum(axis=1)
    return float(np.median(ahead))
