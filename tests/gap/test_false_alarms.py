"""Goodness-of-fit tests hold their false-alarm rate on null data (issue 28, d3).

Each test here compares a statistic with the distribution the diagnosis assumes for it, on data whose truth is
known; the tolerances are stated in units of that distribution's own spread, so a model of the noise that is
off by the amounts found (timing: the stamps' quantum left out, 1.5x the variance; pulses: least squares' se
0.4-0.8x the true scatter, and a random walk of the angle left out, 3-4x) fails them.
"""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from station.gap.api import diagnose
from station.gap.rawstreams import _pulse_lsq
from station.interchange import read_session
from station.twin.config import default_twin

generator = pytest.importorskip("indep.generator")  # tests/indep, the project's second generator

PULSES_PER_REV = 16384
TICK_S = 5e-8
REPS = 80  # records per Monte Carlo check


def _edges(rng: np.random.Generator, diffusion: float, jitter_s: float) -> np.ndarray:
    """Stamped pulse edges (ticks of TICK_S, Gaussian jitter) of a rate 0.5 (1 - 0.9 sin psi + 0.05 cos 2psi) rad/s
    at 5 Hz over 2 s, the angle carrying a random walk of density `diffusion` (rad^2/s): white rate noise."""
    w, c0 = 2 * math.pi * 5.0, 0.5
    harmonics = ((1, 0.0, -0.9 * c0), (2, 0.05 * c0, 0.0))  # (j, cos part, sin part) of the rate

    def phi(t):
        return c0 * t + sum(
            a * np.sin(j * w * t) / (j * w) + b * (1 - np.cos(j * w * t)) / (j * w) for j, a, b in harmonics
        )

    def rate(t):
        return c0 + sum(a * np.cos(j * w * t) + b * np.sin(j * w * t) for j, a, b in harmonics)

    grid = np.linspace(0.0, 2.02, 40_400)
    levels = np.arange(1, int(phi(np.array([2.0]))[0] * PULSES_PER_REV / (2 * math.pi))) * (
        2 * math.pi / PULSES_PER_REV
    )
    t = np.interp(levels, phi(grid), grid)
    for _ in range(4):  # Newton on phi(t) = level
        t = t - (phi(t) - levels) / rate(t)
    if diffusion:
        walk = np.cumsum(rng.normal(0.0, np.sqrt(diffusion * np.diff(t, prepend=0.0))))
        t = t - walk / rate(t)
    return np.sort(np.floor((t + rng.normal(0.0, jitter_s, t.size)) / TICK_S) * TICK_S)


def pulse_chi2_per_dof(diffusion: float, jitter_s: float, seed: int, reps: int = REPS) -> tuple[float, float, float]:
    """Mean over `reps` records of (harmonic - its mean over the records)^2 / the variance the test assumes (the se
    and the walk's covariance at the density the record implies); the same without the walk's term; and the
    median of that density."""
    rng = np.random.default_rng(seed)
    sd_stamp = math.sqrt(jitter_s**2 + TICK_S**2 / 12.0)
    fits = []
    for _ in range(reps):
        t = _edges(rng, diffusion, jitter_s)
        fits.append(_pulse_lsq(SimpleNamespace(pulse_t=t), np.ones(t.size, int), 2 * math.pi * 5.0, 0.0,
                               PULSES_PER_REV, TICK_S, sd_stamp))  # fmt: skip
    meas = np.array([f.meas for f in fits])
    dev2 = (meas - meas.mean(axis=0)) ** 2 * reps / (reps - 1)
    var = np.array([f.se**2 + f.walk_density * np.diag(f.walk_unit) for f in fits])
    white = np.array([f.se**2 for f in fits])
    density = float(np.median([f.walk_density for f in fits]))
    return float(np.mean(dev2 / var)), float(np.mean(dev2 / white)), density


# The mean of 6 x REPS squared standardised values has sd sqrt(2 / (6 REPS)) = 0.065 when the variance model is
# right: 1 +- 0.25 is 3.9 sd. Ordinary least squares (no 1 / rate^2 weights) gives 0.38-0.65 on such records,
# and leaving the walk out 3.2-3.6 at these densities (bench figures in BENCHMARKS.md, issue 28 d3).
TOLERANCE = 0.25


def test_the_pulse_harmonics_se_is_the_true_scatter_of_a_rate_that_swings():
    """Stamp jitter 1e-7 s and the 50 ns quantum: the angle's error at an edge is rate x stamp error, so its
    variance follows rate^2; weighted least squares gives the harmonics' true scatter (least squares did not)."""
    chi2, _, density = pulse_chi2_per_dof(0.0, 1e-7, 1)
    assert abs(chi2 - 1.0) < TOLERANCE, chi2
    assert density < 1e-12  # no walk: the scatter is the stamps' (the excess estimate is 0 or of order its noise)


@pytest.mark.parametrize("diffusion", [1e-10, 1e-9])
def test_white_rate_noise_walks_the_angle_and_the_test_allows_for_it(diffusion):
    """White rate noise of density D (the window mean of 4.3e-7 rad/s over 560 s: D = 1e-10 rad^2/s) is a random
    walk of the angle at the edges; its density is estimated from the scatter beyond the stamps' (within 30 %:
    the moment estimate from ~2600 edges) and its covariance makes the harmonics' scatter the one assumed."""
    chi2, _, density = pulse_chi2_per_dof(diffusion, 1e-7, 2)
    assert abs(chi2 - 1.0) < TOLERANCE, chi2
    assert density == pytest.approx(diffusion, rel=0.3)


def test_a_stated_jitter_without_resolution_keeps_the_timing_test_at_its_level(tmp_path):
    """A null of tests/indep's generator (640 points, 576 period identities; jitter 2e-8 s in 50 ns ticks) whose
    session.json states the jitter but not the resolution: chi^2 / dof of the period identities is 1 within
    4 sd = 4 sqrt(2 / 576) = 0.24; without the ticks' q^2 / 12 in the stamp's variance it is 1.5."""
    rng = np.random.default_rng([28, 3])
    design = generator.equal_angle_design(
        64, (1.0, 2.0, 3.5, 4.0, 5.25, 6.0, 7.5, 8.0, 10.0), window_revs=5, max_window_s=600.0
    )
    noise = generator.Noise(rate_sigma_radps=5e-7, rate_form="per_window", timing_sigma_s=2e-8, grating_noise_m=1e-9)
    truth = generator.Truth(generator.random_coefficients(rng), noise=noise)
    generator.write_session(tmp_path / "s", design, truth, rng)
    meta_path = tmp_path / "s" / "session.json"
    meta = json.loads(meta_path.read_text())
    del meta["timing"]["timer_resolution_s"]
    meta_path.write_text(json.dumps(meta))
    rep = diagnose(read_session(tmp_path / "s"), default_twin(), suggest=False)
    (test,) = [t for t in rep.where["structure_tests_before"] if t["name"] == "timing_goodness_of_fit"]
    assert test["dof"][0] >= 500
    assert abs(test["F"] - 1.0) < 4 * math.sqrt(2.0 / test["dof"][0]), test
    assert rep.verdict.verdict == "no_gap", rep.verdict.text
