"""Reference marks and frequency monitor: line codec, frequency stability, and the real
driver against its emulator over a pty and a sim:// line, the crossings coming from the world's crank.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout, Disconnected, FrameError
from drivers.pty_link import Fault
from drivers.reference_marks import driver as r

pytestmark = pytest.mark.timeout(60)


# ---------------------------------------------------------------- codec


def test_line_roundtrip_and_nmea_checksum() -> None:
    line = r.encode_line("Z", 12, "0001E240")
    assert line.endswith(b"\r\n")
    body = b"Z,12,0001E240"
    x = 0
    for b in body:
        x ^= b
    assert line == b"$" + body + b"*%02X\r\n" % x
    assert r.decode_line(line[:-2]) == ["Z", "12", "0001E240"]


def test_bad_lines_raise_typed_errors() -> None:
    good = r.encode_line("H", "00000001")[:-2]
    with pytest.raises(ChecksumError):
        r.decode_line(good[:-2] + (b"00" if good[-2:] != b"00" else b"01"))
    for bad in (b"", b"H,1*00", good[: len(good) // 2], b"$H,1*ZZ"):
        with pytest.raises(FrameError):
            r.decode_line(bad)


def test_frequency_stability_is_the_seed_formula() -> None:
    rng = np.random.default_rng(3)
    periods = 0.1 * (1 + 1e-4 * rng.standard_normal(10))
    t = np.concatenate(([5.0], 5.0 + np.cumsum(periods)))
    est = r.frequency_stability(t)
    f_e = 1 / periods
    fbar = f_e.mean()
    seed = (1 / (3 * fbar)) * math.sqrt(np.sum((f_e - fbar) ** 2))
    assert est.f_hz == pytest.approx(fbar, rel=1e-15)
    assert est.sigma_rel == pytest.approx(seed, rel=1e-12)
    assert np.allclose(est.periods_s, periods)


def test_frequency_stability_validates_input() -> None:
    with pytest.raises(ValueError):
        r.frequency_stability([0.0, 0.1])
    with pytest.raises(ValueError):
        r.frequency_stability([0.0, 0.2, 0.1])


# ---------------------------------------------------------------- driver against emulator


def test_crossings_are_the_worlds(reference_rig) -> None:
    world, _, ref = reference_rig
    ref.start()
    got = ref.crossings(6, timeout_s=2.0)
    assert [c.n for c in got] == list(range(got[0].n, got[0].n + 6))
    t = np.array([c.t_s for c in got])
    true = world.reference_crossings_s(t[0] - 1e-6, t[-1] + 1e-6)
    assert len(true) == 6
    assert np.max(np.abs(t - true)) <= 25e-9 + 1e-12  # 50 ns tick, rounded
    st = ref.status()
    assert st["reporting"] and st["alarm"] == 0 and st["crossings"] >= 6


def test_measured_frequency_and_stability(reference_rig) -> None:
    world, _, ref = reference_rig
    ref.start()
    est = ref.measure_frequency(periods=10, timeout_s=2.0)
    f_true = world.crank.speed_radps(world.clock.now_s()) / (2 * math.pi)
    # a 50 ns time stamp on a 0.1 s period: 5e-7 relative per period
    assert est.f_hz == pytest.approx(f_true, rel=2e-6)
    assert est.sigma_rel < 5e-6
    assert len(est.periods_s) == 10


def test_queries_mid_stream_lose_no_crossing(reference_rig) -> None:
    _, _, ref = reference_rig
    ref.start()
    first = ref.next_crossing(timeout_s=2.0)
    t_end = time.monotonic() + 0.5  # five crossings come and go while we query
    while time.monotonic() < t_end:
        ref.status()
    rest = ref.crossings(8, timeout_s=2.0)
    assert [c.n for c in rest] == list(range(first.n + 1, first.n + 9))
    assert ref.lost_crossings == 0


@pytest.mark.parametrize(
    ("fault", "error"),
    [(Fault.CRC_ERROR, ChecksumError), (Fault.GARBLE, FrameError), (Fault.TRUNCATE, FrameError)],
)
def test_damaged_line_raises_then_continues(reference_rig, fault, error) -> None:
    _, emu, ref = reference_rig
    ref.start()
    ref.next_crossing(timeout_s=2.0)
    emu.inject(fault)
    with pytest.raises(error):
        for _ in range(50):
            ref.next_crossing(timeout_s=2.0)
    c = ref.next_crossing(timeout_s=2.0)
    assert c.n >= 1


@pytest.mark.parametrize(("fault", "code"), [(Fault.SIGNAL_LOSS, 1), (Fault.OVERSPEED, 2)])
def test_alarm_raises_device_fault_while_active(reference_rig, fault, code) -> None:
    _, emu, ref = reference_rig
    ref.start()
    ref.next_crossing(timeout_s=2.0)
    emu.inject(fault, count=None)
    with pytest.raises(DeviceFault) as info:
        for _ in range(50):
            ref.next_crossing(timeout_s=2.0)
    assert info.value.field == "alarm" and info.value.value == code
    t0 = time.monotonic()
    with pytest.raises(DeviceFault):  # raised again at the next heartbeat: bounded
        ref.next_crossing(timeout_s=5.0)
    assert time.monotonic() - t0 < 2.5
    assert ref.status()["alarm"] == code
    emu.clear_fault(fault)
    ref.next_crossing(timeout_s=2.0)
    assert ref.alarm == 0


def test_no_answer_is_retried_then_times_out(reference_rig) -> None:
    _, emu, ref = reference_rig
    emu.inject(Fault.NO_ANSWER, count=1)
    assert ref.status()["reporting"] is False  # the retry got through
    emu.inject(Fault.NO_ANSWER, count=None)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="after 3 attempts"):
        ref.status()
    assert time.monotonic() - t0 < 3 * ref.timeout_s + 0.5


def test_silent_device_times_out(reference_rig) -> None:
    _, emu, ref = reference_rig
    ref.start()
    ref.next_crossing(timeout_s=2.0)
    emu.inject(Fault.NO_ANSWER, count=None)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout):
        for _ in range(100):
            ref.next_crossing(timeout_s=10.0)
    assert time.monotonic() - t0 < ref.silence_s + 1.0


def test_disconnect_mid_stream(reference_rig) -> None:
    _, emu, ref = reference_rig
    ref.start()
    ref.next_crossing(timeout_s=2.0)
    emu.inject(Fault.DISCONNECT)
    with pytest.raises(Disconnected):
        for _ in range(100):
            ref.next_crossing(timeout_s=2.0)
    ref.close()
