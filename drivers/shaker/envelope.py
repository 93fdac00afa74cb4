"""The shaker table's envelope: its [shaker] section and the limit checks that the driver (before anything is
sent), the emulator (as the controller's own envelope) and the procedures (in planning) share.

A random test's peaks are taken at 3 sigma, where controllers clip the drive; accelerations in
units of standard gravity, as vibration controllers count them (seed 002 section 4).
"""

from __future__ import annotations

import math

from drivers.errors import LimitError
from drivers.shaker.protocol import DEVICE
from station.validation import in_range, settings, spec

G_STANDARD_MPS2 = 9.80665
PEAK_SIGMAS = 3.0  # random drive clipped at 3 sigma


@settings
class ShakerSection:
    """[shaker] of a station file: the controller's port and the table's envelope."""

    port: str | None = spec((bool, "a device path such as /dev/ttyUSB5"), optional=True)
    baud: int = spec(in_range(1200, 921_600))
    freq_min_hz: float = spec(in_range(0.0, 100.0, lo_open=True))
    freq_max_hz: float = spec(in_range(1.0, 20_000.0))
    displacement_max_m: float = spec(in_range(0.0, 0.1, lo_open=True))  # peak
    velocity_max_mps: float = spec(in_range(0.0, 10.0, lo_open=True))  # peak
    accel_max_g: float = spec(in_range(0.0, 300.0, lo_open=True))  # peak
    thrust_sine_n: float = spec(in_range(0.0, 1e6, lo_open=True))  # peak
    thrust_random_n: float = spec(in_range(0.0, 1e6, lo_open=True))  # RMS
    moving_mass_kg: float = spec(in_range(0.0, 10_000.0, lo_open=True))  # armature and slip table
    payload_kg: float = spec(in_range(0.0, 10_000.0))  # what is mounted: fixture, dampers, IMU
    payload_max_kg: float = spec(in_range(0.0, 10_000.0, lo_open=True))
    ramp_max_s: float = spec(in_range(0.0, 600.0, lo_open=True))


def _limit(field: str, value: float, allowed: str, why: str) -> LimitError:
    return LimitError(DEVICE, why, field=field, value=round(value, 6), allowed=allowed)


def _check_payload(lim: ShakerSection) -> None:
    if lim.payload_kg > lim.payload_max_kg:
        raise _limit("payload_kg", lim.payload_kg, f"<= {lim.payload_max_kg:g} kg", "payload too heavy")


def check_sine(lim: ShakerSection, freq_hz: float, amp_g: float) -> None:
    """A sine test within the table's envelope, else LimitError naming the quantity (nothing is sent)."""
    _check_payload(lim)
    if not (math.isfinite(freq_hz) and lim.freq_min_hz <= freq_hz <= lim.freq_max_hz):
        raise _limit("freq_hz", freq_hz, f"{lim.freq_min_hz:g} .. {lim.freq_max_hz:g} Hz", "frequency out of range")
    force_g = lim.thrust_sine_n / ((lim.moving_mass_kg + lim.payload_kg) * G_STANDARD_MPS2)
    top_g = min(lim.accel_max_g, force_g)
    if not (math.isfinite(amp_g) and 0.0 < amp_g <= top_g):
        raise _limit("amp_g", amp_g, f"0 < amp_g <= {top_g:.4g} g (acceleration and sine thrust)", "too strong")
    w = 2 * math.pi * freq_hz
    a = amp_g * G_STANDARD_MPS2
    for name, value, top, unit, power in (
        ("velocity_mps", a / w, lim.velocity_max_mps, "m/s", 1),
        ("displacement_m", a / w**2, lim.displacement_max_m, "m", 2),
    ):
        if value > top:
            most_g = top * w**power / G_STANDARD_MPS2
            raise _limit(
                name, value, f"<= {top:g} {unit}: at {freq_hz:g} Hz at most {most_g:.4g} g", "beyond the table"
            )


def random_sigmas(rms_g: float, lo_hz: float, hi_hz: float) -> tuple[float, float]:
    """RMS displacement (m) and velocity (m/s) of a flat acceleration PSD of rms_g over [lo_hz, hi_hz]."""
    psd = (rms_g * G_STANDARD_MPS2) ** 2 / (hi_hz - lo_hz)  # (m/s^2)^2 / Hz
    var_d = psd / (2 * math.pi) ** 4 * (lo_hz**-3 - hi_hz**-3) / 3.0
    var_v = psd / (2 * math.pi) ** 2 * (1.0 / lo_hz - 1.0 / hi_hz)
    return math.sqrt(var_d), math.sqrt(var_v)


def check_random(lim: ShakerSection, rms_g: float, lo_hz: float, hi_hz: float) -> None:
    """A random test within the table's envelope (peaks at 3 sigma), else LimitError (nothing is sent)."""
    _check_payload(lim)
    band = f"{lim.freq_min_hz:g} .. {lim.freq_max_hz:g} Hz"
    for name, f in (("lo_hz", lo_hz), ("hi_hz", hi_hz)):
        if not (math.isfinite(f) and lim.freq_min_hz <= f <= lim.freq_max_hz):
            raise _limit(name, f, band, "band edge out of range")
    if not lo_hz < hi_hz:
        raise _limit("lo_hz", lo_hz, f"< hi_hz = {hi_hz:g} Hz", "empty band")
    force_g = lim.thrust_random_n / ((lim.moving_mass_kg + lim.payload_kg) * G_STANDARD_MPS2)
    top_g = min(lim.accel_max_g / PEAK_SIGMAS, force_g)
    if not (math.isfinite(rms_g) and 0.0 < rms_g <= top_g):
        raise _limit("rms_g", rms_g, f"0 < rms_g <= {top_g:.4g} g (3-sigma peaks and random thrust)", "too strong")
    sd, sv = random_sigmas(rms_g, lo_hz, hi_hz)
    if PEAK_SIGMAS * sv > lim.velocity_max_mps:
        raise _limit("velocity_mps", PEAK_SIGMAS * sv, f"<= {lim.velocity_max_mps:g} m/s (3 sigma)", "too fast")
    if PEAK_SIGMAS * sd > lim.displacement_max_m:
        allowed = f"<= {lim.displacement_max_m:g} m (3 sigma): raise lo_hz or lower rms_g"
        raise _limit("displacement_m", PEAK_SIGMAS * sd, allowed, "beyond the stroke")


def check_ramp(lim: ShakerSection, ramp_s: float) -> None:
    if not (math.isfinite(ramp_s) and 0.0 < ramp_s <= lim.ramp_max_s):
        raise _limit("ramp_s", ramp_s, f"0 < ramp_s <= {lim.ramp_max_s:g} s", "ramp out of range")
