"""The effects of physics.md's table that a real station shows and a twin may leave out: one module each.

`EFFECTS` lists them in the table's order, each module's `EFFECT` (station.twin.effects.base.Effect). The twin
(station.twin.config, station.twin.inputs, station.twin.measurement), the gap diagnosis's candidates
(station.gap.candidates), its
validation (station.gap.validate) and report (station.gap.report) take everything about an effect from there. Adding
an effect
is a module here, its line below and its tests (README, "Adding an effect"); `registered` adds one for a test.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from types import MappingProxyType

from station.twin.effects import (
    bias_drift,
    cross_coupling,
    frequency_error,
    index_harmonics,
    lateral_resonance,
    mount_misalignment,
    odd_quadratic,
    parasitic_rotation,
    readhead_latency,
    waveform_fundamental,
    waveform_harmonics,
)
from station.twin.effects.base import Effect, JointBound, Param, Params, Terms

_REGISTRY: dict[str, Effect] = {
    m.EFFECT.name: m.EFFECT
    for m in (
        waveform_fundamental,
        waveform_harmonics,
        parasitic_rotation,
        lateral_resonance,
        odd_quadratic,
        cross_coupling,
        index_harmonics,
        mount_misalignment,
        bias_drift,
        readhead_latency,
        frequency_error,
    )
}
EFFECTS: Mapping[str, Effect] = MappingProxyType(_REGISTRY)  # a live, read-only view


@contextmanager
def registered(effect: Effect) -> Iterator[Effect]:
    """`effect` in the registry for the duration (a test's toy effect), then gone again."""
    if effect.name in _REGISTRY:
        raise ValueError(f"effect {effect.name!r} is already registered")
    _REGISTRY[effect.name] = effect
    try:
        yield effect
    finally:
        del _REGISTRY[effect.name]


__all__ = ["EFFECTS", "Effect", "JointBound", "Param", "Params", "Terms", "registered"]
