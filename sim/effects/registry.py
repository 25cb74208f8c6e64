"""The effects a scene may name, their parameter models, and how they are applied.

A scene lists effects as raw tables, ``{"name": "noise", "std_counts": 4}``;
:func:`parse_effects` validates them against ``EFFECT_MODELS`` (one line per
mistake). :class:`EffectPlan` splits them by where they act:

- ``kpa``: on pressure, before the insole's transfer curve (hysteresis, creep),
- ``counts``: on float counts (crosstalk, dead/shorted lines, noise),
- ``schedule``: on the packet schedule (drift, loss, offset, jitter, unplug),
- ``line``: on the encoded bytes (corruption).

Within a place they run in a fixed physical order (below), whatever the
scene's order. An effect not named is never constructed nor called.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Final, Protocol

import numpy as np
from pydantic import ValidationError
from scotti.sim import SimError
from scotti.sim.effects.base import EFFECT_CALLS, Effect, EffectParams
from scotti.sim.effects.line import LineCorruption, LineCorruptionParams
from scotti.sim.effects.schedule import PacketSchedule
from scotti.sim.effects.sensor import (
    Crosstalk,
    CrosstalkParams,
    DeadLine,
    DeadLineParams,
    Noise,
    NoiseParams,
)
from scotti.sim.effects.sensor_memory import Creep, CreepParams, Hysteresis, HysteresisParams
from scotti.sim.effects.transport import (
    ClockDriftParams,
    FootOffsetParams,
    JitterParams,
    PacketLossParams,
    UnplugParams,
    apply_clock_drift,
    apply_foot_offset,
    apply_jitter,
    apply_packet_loss,
    apply_unplug,
)

__all__ = ["EFFECT_CALLS", "EFFECT_MODELS", "EffectError", "EffectPlan", "parse_effects"]


class EffectError(SimError):
    """An effect table a scene names is unknown or has bad parameters."""


# Name -> parameter model, in the order effects are applied within their place.
EFFECT_MODELS: Final[dict[str, type[EffectParams]]] = {
    # sensor, on pressure
    "hysteresis": HysteresisParams,
    "creep": CreepParams,
    # sensor, on counts
    "crosstalk": CrosstalkParams,
    "dead_line": DeadLineParams,
    "noise": NoiseParams,
    # transport, on the schedule
    "clock_drift": ClockDriftParams,
    "packet_loss": PacketLossParams,
    "foot_offset": FootOffsetParams,
    "jitter": JitterParams,
    "unplug": UnplugParams,
    # the serial line, on bytes
    "line_corruption": LineCorruptionParams,
}
# Names a scene may still give as effects that are insole parameters (scotti.sim.insole):
# the error says where they go.
_NOW_INSOLE: Final = {
    "gain_spread": "gain_sigma",
    "transfer": "threshold_kpa, p_half_kpa, exponent, saturation_counts",
}
_ORDER: Final = {name: i for i, name in enumerate(EFFECT_MODELS)}
_PLACE: Final = {
    **dict.fromkeys(("hysteresis", "creep"), "kpa"),
    **dict.fromkeys(("crosstalk", "dead_line", "noise"), "counts"),
    **dict.fromkeys(("clock_drift", "packet_loss", "foot_offset", "jitter", "unplug"), "schedule"),
    "line_corruption": "line",
}


def parse_effect(raw: Mapping[str, Any], index: int = 0) -> Effect:
    """One scene table -> an :class:`Effect`; raises ``EffectError`` (one line)."""
    if not isinstance(raw, Mapping) or not isinstance(raw.get("name"), str):
        msg = f"effect #{index + 1} needs a 'name' (one of {', '.join(EFFECT_MODELS)})"
        raise EffectError(msg)
    name = raw["name"]
    model = EFFECT_MODELS.get(name)
    if name in _NOW_INSOLE:
        msg = f"effect {name!r} is part of the insole now: set {_NOW_INSOLE[name]} in [insole]"
        raise EffectError(msg)
    if model is None:
        msg = f"unknown effect {name!r}; known: {', '.join(EFFECT_MODELS)}"
        raise EffectError(msg)
    try:
        params = model.model_validate({k: v for k, v in raw.items() if k != "name"})
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or name
        msg = f"effect {name!r}: {where}: {first['msg']}"
        raise EffectError(msg) from None
    return Effect(name, params, index)


def parse_effects(raw: Iterable[Mapping[str, Any]]) -> tuple[Effect, ...]:
    return tuple(parse_effect(r, i) for i, r in enumerate(raw))


class Stage(Protocol):
    def apply(self, x: np.ndarray) -> np.ndarray: ...


@dataclass
class EffectPlan:
    """The effects of one session, built with their random streams."""

    kpa: list[Stage] = field(default_factory=list)
    counts: list[Stage] = field(default_factory=list)
    schedule: list[Callable[[PacketSchedule], None]] = field(default_factory=list)
    unplugs: list[UnplugParams] = field(default_factory=list)
    line_params: list[tuple[LineCorruptionParams, np.random.Generator]] = field(
        default_factory=list
    )

    @classmethod
    def build(
        cls, effects: Iterable[Effect], *, seed: int, rate_hz: float, mask: np.ndarray
    ) -> EffectPlan:
        plan = cls()
        fmask = mask.astype(np.float32)
        for e in sorted(effects, key=lambda e: (_ORDER[e.name], e.index)):
            plan._add(e, e.rng(seed), rate_hz, fmask)
        return plan

    def _add(self, e: Effect, rng: np.random.Generator, rate_hz: float, mask: np.ndarray) -> None:
        p = e.params
        if isinstance(p, HysteresisParams):
            self.kpa.append(Hysteresis(p, rate_hz))
        elif isinstance(p, CreepParams):
            self.kpa.append(Creep(p, rate_hz))
        elif isinstance(p, CrosstalkParams):
            self.counts.append(Crosstalk(p, mask))
        elif isinstance(p, DeadLineParams):
            self.counts.append(DeadLine(p, mask))
        elif isinstance(p, NoiseParams):
            self.counts.append(Noise(p, rng, mask))
        elif isinstance(p, ClockDriftParams):
            self.schedule.append(partial(apply_clock_drift, p))
        elif isinstance(p, PacketLossParams):
            self.schedule.append(partial(apply_packet_loss, p, rng=rng))
        elif isinstance(p, FootOffsetParams):
            self.schedule.append(partial(apply_foot_offset, p))
        elif isinstance(p, JitterParams):
            self.schedule.append(partial(apply_jitter, p, rng=rng))
        elif isinstance(p, UnplugParams):
            self.schedule.append(partial(apply_unplug, p))
            self.unplugs.append(p)
        elif isinstance(p, LineCorruptionParams):
            self.line_params.append((p, rng))
        else:  # pragma: no cover - EFFECT_MODELS and this switch are kept together
            msg = f"effect {e.name!r} has no implementation"
            raise EffectError(msg)

    def line_stages(self, t0_ns: int) -> list[LineCorruption]:
        return [LineCorruption(p, rng, t0_ns) for p, rng in self.line_params]


def describe_effects() -> dict[str, dict[str, Any]]:
    """Name -> {place, doc, JSON schema of the parameters} (for docs and --help)."""
    return {
        name: {
            "place": _PLACE[name],
            "doc": (model.__doc__ or "").strip(),
            "schema": model.model_json_schema(),
        }
        for name, model in EFFECT_MODELS.items()
    }


# Effects of a plausible real session, for ``scotti sim corpus --effects realistic``.
def realistic_effects(rng: np.random.Generator) -> list[dict[str, Any]]:
    """A draw of everyday imperfections; values inside the documented typical ranges."""
    return [
        {"name": "hysteresis", "fraction": float(rng.uniform(0.03, 0.12)), "tau_s": 0.5},
        {"name": "creep", "fraction": float(rng.uniform(0.02, 0.08)), "tau_s": 30.0},
        {"name": "crosstalk", "fraction": float(rng.uniform(0.005, 0.03))},
        {"name": "noise", "std_counts": float(rng.uniform(2.0, 8.0))},
        {
            "name": "clock_drift",
            "left_ppm": float(rng.uniform(-30, 30)),
            "right_ppm": float(rng.uniform(-30, 30)),
        },
        {"name": "packet_loss", "p_good_to_bad": float(rng.uniform(0.001, 0.01))},
        {"name": "foot_offset", "foot": "right", "offset_ms": float(rng.uniform(-20, 20))},
        {"name": "jitter", "std_ms": float(rng.uniform(0.5, 3.0))},
        {"name": "line_corruption", "flip_rate_per_byte": 1e-7, "garbage_per_s": 0.002},
    ]
