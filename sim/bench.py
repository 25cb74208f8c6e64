"""How fast the simulator makes session files, against real time.

Generates ``minutes`` of a two-foot stream (every action of the contract in turn) in
three timed stages - motion, pressure + sensor effects, packets + file - and
extrapolates to one hour. The target is 100x real time: an hour in < 36 s.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
from scotti.models.contract import ACTIONS, FRAME_RATE_HZ
from scotti.sim.effects.registry import EffectPlan, parse_effects, realistic_effects
from scotti.sim.foot import draw_feet
from scotti.sim.insole import InsoleArray
from scotti.sim.pressure import PressureRenderer
from scotti.sim.scene import PHYSICS_OVERSAMPLE, Scene, ScriptEntry, SubjectModel, build_motion
from scotti.sim.writer import CountsStream, sim_input, write_session

TARGET_RATIO: Final = 100.0


@dataclass(frozen=True)
class BenchResult:
    minutes: float
    frames: int
    motion_s: float
    pressure_s: float
    session_s: float
    file_bytes: int

    @property
    def total_s(self) -> float:
        return self.motion_s + self.session_s  # the session stage renders pressure itself

    @property
    def simulated_s(self) -> float:
        return self.frames / FRAME_RATE_HZ

    @property
    def ratio(self) -> float:
        return self.simulated_s / self.total_s

    def lines(self) -> list[str]:
        hour = 3600.0 / self.ratio
        return [
            f"simulated {self.simulated_s:.0f} s"
            f" ({self.frames} frames x 2 feet, {len(ACTIONS)} actions)",
            f"  motion (sim-body kinematics)     {self.motion_s:8.2f} s",
            f"  pressure + sensor effects only   {self.pressure_s:8.2f} s (measured apart)",
            f"  pressure, packets, session file  {self.session_s:8.2f} s"
            f" ({self.file_bytes / 1e6:.1f} MB)",
            f"  total                            {self.total_s:8.2f} s",
            f"ratio to real time: {self.ratio:.0f}x (target >= {TARGET_RATIO:.0f}x)",
            f"one hour: {hour:.1f} s"
            + (" (measured)" if abs(self.simulated_s - 3600) < 60 else " (extrapolated linearly)"),
        ]


def bench_scene(minutes: float, effects: bool) -> Scene:
    raw = realistic_effects(np.random.default_rng(0)) if effects else []
    return Scene(
        name="bench",
        seed=1,
        subject=SubjectModel(height_m=1.75, mass_kg=72.0, style_seed=3),
        script=[
            ScriptEntry(action=a, duration_s=minutes * 60.0 / len(ACTIONS), stand_s=0.0)
            for a in ACTIONS
        ],
        effects=raw,
    )


def run_bench(minutes: float, effects: bool = False, out: Path | None = None) -> BenchResult:
    scene = bench_scene(minutes, effects)
    t0 = time.perf_counter()
    sim = sim_input(build_motion(scene, PHYSICS_OVERSAMPLE))
    t1 = time.perf_counter()
    feet = draw_feet(sim.foot_length_m, scene.subject.style_seed, scene.seed)
    insole = scene.insole.resolved()
    renderer = PressureRenderer(sim.foot_length_m, feet)
    parsed = parse_effects(scene.effects)
    plan = EffectPlan.build(parsed, seed=scene.seed, rate_hz=sim.rate_hz, mask=renderer.mask)
    stream = CountsStream(sim.loads(), renderer, plan, InsoleArray(insole, scene.seed))
    for i in range(-(-stream.frames // stream.chunk_frames)):
        stream.chunk(i)
    t2 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = out if out is not None else Path(tmp) / "bench.ses"
        t3 = time.perf_counter()
        write_session(
            path,
            sim,
            seed=scene.seed,
            effects=parsed,
            scene=scene.model_dump(),
            feet=feet,
            insole=insole,
        )
        t4 = time.perf_counter()
        size = os.path.getsize(path)
    return BenchResult(minutes, len(sim.com), t1 - t0, t2 - t1, t4 - t3, size)
