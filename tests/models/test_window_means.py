"""Closed-form window means (physics.md) against numerical quadrature."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from station.twin.window_means import window_means


@pytest.mark.parametrize("seed", range(6))
def test_closed_forms_match_quadrature(seed):
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.5, 10.0)
    w = 2 * math.pi * f
    T = 1 / f
    t1 = rng.uniform(0, T)
    Np = int(rng.integers(3, 40))
    t2 = rng.uniform(0, T)
    Tm = t1 + Np * T - t2  # the identity that holds for a perfect frequency
    got = window_means(w, Tm, t1, t2)
    for power, value in zip((1, 2, 3), got, strict=True):
        integral, err = quad(
            lambda t, p=power: math.sin(w * (t - t1)) ** p, 0, Tm, limit=2000, epsabs=1e-14, epsrel=1e-13
        )
        # quad's own error estimate bounds the comparison; the closed form is exact to rounding.
        assert value == pytest.approx(integral / Tm, abs=max(10 * err / Tm, 1e-13))


def test_whole_periods_give_the_nominal_means():
    f, t1 = 8.0, 0.01
    Tm = 100 / f  # window of whole periods: t2 = t1
    s1, s2, s3 = window_means(2 * math.pi * f, Tm, t1, t1)
    assert (float(s1), float(s2), float(s3)) == pytest.approx((0.0, 0.5, 0.0), abs=1e-15)
