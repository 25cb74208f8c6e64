"""Sensor and transport effects; a scene names the ones it wants (see EFFECTS.md)."""

from scotti.sim.effects.registry import EFFECT_MODELS, EffectError, EffectPlan, parse_effects

__all__ = ["EFFECT_MODELS", "EffectError", "EffectPlan", "parse_effects"]
