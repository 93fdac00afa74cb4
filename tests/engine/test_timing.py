"""Integer-period timing capture from time stamps (physics.md) and its cross-check with the grating."""

from __future__ import annotations

import math

import numpy as np
import pytest

from station.engine.timing import TimingFault, capture_timing, cross_check

F_HZ = 10.0
T_S = 1 / F_HZ


def crossings(first_s: float, n: int, freq_hz: float = F_HZ) -> np.ndarray:
    return first_s + np.arange(n) / freq_hz


def test_t1_t2_np_from_the_stamps() -> None:
    open_s, close_s = 100.0, 100.0 + 560.13359
    c = crossings(99.95, 5610)  # from before the opening to past the closing
    w = capture_timing(open_s, close_s, c, F_HZ)
    assert w.Tm_s == pytest.approx(560.13359, abs=1e-9)
    assert w.t1_s == pytest.approx(0.05, abs=1e-9)  # 100.05 - 100.0
    assert w.Np == 5601  # 100.05 + 5601 * 0.1 = 660.15 >= 660.13359, the first at or after Tm
    assert w.t2_s == pytest.approx(660.15 - close_s, abs=1e-9)
    assert w.t1_s + w.Np * T_S - w.Tm_s == pytest.approx(w.t2_s, abs=1e-9)  # the identity of physics.md


def test_a_missed_or_spurious_reference_crossing_is_a_fault_not_a_number() -> None:
    # One crossing lost in 5601 periods changes the counted frequency by only 1.8e-4 (inside the 5e-4 of
    # Table 4), so the gaps are checked one by one: a lost crossing is a gap of 2 periods.
    c = np.delete(crossings(99.95, 5610), 3000)
    with pytest.raises(TimingFault, match=r"2\.000 periods apart .* missed or spurious"):
        capture_timing(100.0, 660.13359, c, F_HZ)
    c = np.sort(np.append(crossings(99.95, 5610), 400.0123))
    with pytest.raises(TimingFault, match="missed or spurious"):
        capture_timing(100.0, 660.13359, c, F_HZ)


def test_a_window_without_its_closing_crossing_is_a_fault() -> None:
    with pytest.raises(TimingFault, match="need one after the opening and one at or after the closing"):
        capture_timing(100.0, 660.13359, crossings(99.95, 100), F_HZ)
    with pytest.raises(TimingFault, match="not after its opening"):
        capture_timing(100.0, 99.0, crossings(99.95, 100), F_HZ)


def test_static_window_has_no_t1_t2() -> None:
    w = capture_timing(5.0, 565.84, np.zeros(0), 0.0)
    assert (w.t1_s, w.t2_s, w.Np) == (None, None, None) and w.Tm_s == pytest.approx(560.84)


@pytest.mark.parametrize(("lag_s", "faults"), [(0.0, False), (2e-5, False), (1e-3, True)])
def test_grating_cross_check(lag_s: float, faults: bool) -> None:
    # Grating: z = A0 sin(w (t - t0)), mid-stroke upwards at t0 + k T. Crossings stamped lag_s late.
    # The tolerance, 2e-3 rad of phase, is 32 us at 10 Hz: 20 us passes, 1 ms does not.
    t0 = 10.0123
    t = 10.0 + np.arange(2000) / 5000.0
    z = 0.03 * np.sin(2 * math.pi * F_HZ * (t - t0))
    c = crossings(t0, 4) + lag_s
    if faults:
        with pytest.raises(TimingFault, match="disagree"):
            cross_check(c, t, z, F_HZ)
    else:
        check = cross_check(c, t, z, F_HZ)
        assert check["phase_error_rad"] == pytest.approx(2 * math.pi * F_HZ * lag_s, abs=1e-6)
        assert check["grating_freq_hz"] == pytest.approx(F_HZ, rel=1e-9)
