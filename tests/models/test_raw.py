"""Raw streams: pulse edges at exact levels, the grating's harmonics, the reference crossings."""

import math

import numpy as np
import pytest

from station.twin.config import NoiseModel, TwinConfig
from station.twin.measurement import simulate_point
from station.twin.plan import PointSpec

EXACT = TwinConfig(noise=NoiseModel(timer_tick_s=0.0))
Q = 2 * math.pi / 16384


@pytest.fixture(scope="module", params=[0.0, 10.0], ids=["static", "10Hz"])
def point(request):
    return simulate_point(PointSpec(30.0, request.param, 16384 * 5), EXACT, np.random.default_rng(4), raw=True)


def test_every_edge_sits_on_a_pulse_level(point):
    r = point.raw
    phi = point.window.phi_rad(r.pulse_t)
    # cubic Hermite on T/512 cells: < h^4 max|phi''''| / 384 = 6e-12 rad at 10 Hz
    assert np.max(np.abs(phi - Q * np.round(phi / Q))) < 1e-11
    # in time: 1e-11 rad over the slowest edge's rate, far below the 50 ns tick
    assert np.all(np.diff(r.pulse_t) >= 0)


def test_net_count_at_tm_is_the_preset(point):
    r = point.raw
    upto = r.pulse_t <= point.true_Tm_s * (1 + 1e-13)
    assert int(r.pulse_dir[upto][1:].sum()) == 16384 * 5  # the opening edge is not counted
    # up/down: after an up crossing of level k the count is k, after a down crossing k - 1
    levels = np.round(point.window.phi_rad(r.pulse_t) / Q).astype(np.int64)
    count = levels - (r.pulse_dir < 0)
    assert np.array_equal(np.diff(count), r.pulse_dir[1:].astype(np.int64))


def test_no_edge_is_missed_between_grid_points():
    """Dense check of a 10 Hz stretch: count level crossings of phi on a 1 us grid."""
    sp = simulate_point(PointSpec(0.0, 10.0, 16384), EXACT, np.random.default_rng(5), raw=True)
    t = np.arange(0, 0.5, 1e-6)
    level = np.floor(sp.window.phi_rad(t) / Q)
    changes = np.count_nonzero(np.diff(level))
    got = np.count_nonzero((sp.raw.pulse_t > 0) & (sp.raw.pulse_t < t[-1]))
    assert got == changes


def test_grating_harmonics_recover_the_waveform():
    f = 9.0
    cfg = EXACT.with_effect("waveform_fundamental", z0=-1.299e-4, z1=3.2e-6, Zc1=2e-5).with_effect(
        "waveform_harmonics", Zs2=2.4e-6, Zc2=-4.2e-6
    )
    sp = simulate_point(PointSpec(0.0, f, 16384 * 2), cfg, np.random.default_rng(6), raw=True)
    t, z = sp.raw.grating_t, sp.raw.grating_z
    psi = 2 * math.pi * f * t + sp.window.gamma0_rad
    n = int(len(t) // (5000 / f) * (5000 / f))  # whole periods (5000/f samples each, 555.6 at 9 Hz: near enough)
    X = np.column_stack([np.ones(n)] + [g(j * psi[:n]) for j in (1, 2, 3) for g in (np.sin, np.cos)])
    coef = np.linalg.lstsq(X, z[:n], rcond=None)[0]
    w = 2 * math.pi * f
    expected = [0.0, 0.03 - 1.299e-4 + 3.2e-6 * w, 2e-5, 2.4e-6, -4.2e-6, 0.0, 0.0]
    # 1 nm quantisation of the read head: the least-squares coefficients are good to far below 1 nm
    np.testing.assert_allclose(coef, expected, atol=2e-10)


def test_reference_crossings_are_zero_phase_one_period_apart():
    sp = simulate_point(PointSpec(0.0, 8.0, 16384), EXACT, np.random.default_rng(7), raw=True)
    ref = sp.raw.reference_t
    psi = 2 * math.pi * 8.0 * ref + sp.window.gamma0_rad
    assert np.max(np.abs(np.sin(psi))) < 1e-9
    np.testing.assert_allclose(np.diff(ref), 1 / 8.0, atol=1e-12)
    assert ref[0] == pytest.approx(sp.record.t1_s, abs=1e-12)


def test_raw_streams_too_large_for_memory_are_refused_before_allocation() -> None:
    # A static window at 90 deg precesses on k0 alone: one revolution lasts 2 pi / k0 = 11.6 h of a
    # 5 kHz record (2e8 samples, 1.7 GB per array): refused with the sizes, in milliseconds.
    from station.twin.raw import RawStreamsTooLargeError

    with pytest.raises(RawStreamsTooLargeError, match=r"grating samples .* exceed"):
        simulate_point(PointSpec(90.0, 0.0, 16384), TwinConfig(), np.random.default_rng(0), raw=True)
