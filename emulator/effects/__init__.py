"""Unmodelled effects of the emulated vehicle: the reasons real data differ from the paper's model.

Each effect is a plug-in behind one contract (``Effect`` in ``base``), one module per effect, switched on
by an effects file (TOML, one table per effect) that ``EffectSet.load`` reads. ``EffectSet.ideal()`` is
the ideal vehicle on which the paper's assumptions hold. See docs/effects.md.
"""
from .base import Effect, EffectsError, Param, Plant
from .effect_set import REGISTRY, EffectSet

__all__ = ["Effect", "EffectSet", "EffectsError", "Param", "Plant", "REGISTRY"]
