"""Shared, seeded sessions for the gap-diagnosis tests, each simulated and diagnosed once per run.

The "real" sessions are the twin with an effect injected at a given signal-to-noise
ratio after the calibrated terms are projected out (station.gap.validate), so
every tolerance below can be stated in units of the noise.
"""

from __future__ import annotations

import functools

import pytest

from station.gap.api import diagnose
from station.gap.report import GapReport
from station.gap.validate import Case, make_session
from station.session import Session
from station.twin.config import TwinConfig, default_twin


@functools.cache
def _twin() -> TwinConfig:
    return default_twin()


@functools.cache
def _session(kind: str, effect: str | None, snr: float, seed: int) -> tuple[Session, dict]:
    return make_session(Case("seed000", kind, effect, snr, seed), _twin())


@functools.cache
def _report(kind: str, effect: str | None, snr: float, seed: int, suggest: bool) -> GapReport:
    return diagnose(_session(kind, effect, snr, seed)[0], _twin(), suggest=suggest)


@pytest.fixture(scope="session")
def twin() -> TwinConfig:
    return _twin()


@pytest.fixture(scope="session")
def seed000_session():
    """Factory: (session, injected parameters) of the seed-000 design (40 points, 10 positions x 8/9/10 Hz + static)."""
    return _session


@pytest.fixture(scope="session")
def seed000_report():
    """Factory: the diagnosis of `seed000_session(kind, effect, snr, seed)` against the default twin."""

    def report(kind: str, effect: str | None, snr: float, seed: int, suggest: bool = False) -> GapReport:
        return _report(kind, effect, snr, seed, suggest)

    return report
