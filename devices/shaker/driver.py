"""Electrodynamic shaker: the vibration controller of a slip table (sine and random control), ASCII over RS-232.

The station's second kind of table (seed 002 §4: an electrodynamic bench of 1-2500 Hz, sine
thrust 50 kN, random thrust 50 kN RMS), beside the crank-driven table of 0.1-10 Hz.

Command  `<text>*<crc>\\n`     Reply  `<OK|ER> <data>*<crc>\\r\\n`
crc: CRC-16/CCITT-FALSE (devices.serial_port.crc16) of the text before `*`, four upper-case
hex digits. Commands:

    IDN?                          OK <model> <serial>
    SINE <freq_hz> <amp_g>        set a sine test (peak acceleration of the control accelerometer)
    RAND <rms_g> <lo_hz> <hi_hz>  set a random test: flat acceleration PSD over the band
    START <ramp_s>                drive up to the set level over ramp_s
    STOP <ramp_s>                 ramp down over ramp_s and open the loop
    ABORT                         drive off at once
    STAT?                         OK <state> <mode> <level_g> <alarm>
    ALARM:CLR                     clear a latched alarm

States IDLE, RAMP_UP, RUN, RAMP_DOWN, ALARM; modes NONE, SINE, RANDOM; level: peak g (sine) or
RMS g (random) now; alarm `--` or OVERTRAVEL, AMP_TEMP, COLA (control loss), INTERLOCK. An alarm
stops the drive at once and latches. ER codes: BUSY (the table runs), RANGE (outside the
controller's envelope), ALARM (start refused while an alarm is latched), SYNTAX.

Limits (the [shaker] section, checked here before anything is sent and by the procedures in
planning): frequency range, peak displacement, velocity and acceleration, sine and random
thrust for the moving mass plus the payload, payload mass. Accelerations are in units of
standard gravity, as vibration controllers count them. A random test's peaks are taken at
3 sigma, where controllers clip the drive.

Errors: no reply -> DeviceTimeout; malformed or truncated reply -> FrameError; bad crc ->
ChecksumError; ER -> DeviceFault (field "reply"); a latched alarm seen by `check()` ->
DeviceFault (field "alarm"); outside the limits -> LimitError (nothing sent); port gone ->
Disconnected. Queries, settings, STOP and ABORT are retried; START is not (it may have started).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

from devices.config import in_range, spec
from devices.errors import ChecksumError, DeviceFault, DeviceTimeout, DriverError, FrameError, LimitError
from devices.registry import DeviceKind
from devices.serial_port import SerialDevice, crc16, with_retries
from station.clock import Clock

DEVICE = "shaker controller"
G_STANDARD_MPS2 = 9.80665
PEAK_SIGMAS = 3.0  # random drive clipped at 3 sigma
STATES = ("IDLE", "RAMP_UP", "RUN", "RAMP_DOWN", "ALARM")
MODES = ("NONE", "SINE", "RANDOM")


@dataclass(frozen=True)
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


# ---------------------------------------------------------------- line codec


def encode_line(text: str) -> bytes:
    """`text*CRC` without the terminator."""
    body = text.encode("ascii")
    return body + b"*%04X" % crc16(body)


def decode_line(line: bytes) -> bytes:
    """The text of a `text*CRC` line (terminator stripped); FrameError / ChecksumError when bad."""
    body, sep, crc = line.rpartition(b"*")
    if not sep or len(crc) != 4:
        raise FrameError(DEVICE, f"line without checksum (truncated?): {line!r}")
    try:
        got = int(crc, 16)
    except ValueError as exc:
        raise FrameError(DEVICE, f"malformed checksum in {line!r}") from exc
    if got != crc16(body):
        raise ChecksumError(DEVICE, f"reply {line!r}: crc {got:04X} != computed {crc16(body):04X}")
    return body


@dataclass(frozen=True)
class ShakerStatus:
    state: str
    mode: str
    level_g: float
    alarm: str | None

    @property
    def running(self) -> bool:
        return self.state in ("RAMP_UP", "RUN", "RAMP_DOWN")


class ShakerController(SerialDevice):
    """Driver of the vibration controller; `limits` is the table's envelope (its config section)."""

    DEVICE = DEVICE

    def __init__(
        self, port: str, limits: ShakerSection, *, baud: int = 115_200, timeout_s: float = 0.5, retries: int = 2
    ) -> None:
        super().__init__(port, baud)
        self.limits = limits
        self.timeout_s = timeout_s
        self.retries = retries

    def _before_close(self) -> None:
        """Bring a running table to rest (best effort, one try) before the port closes."""
        with contextlib.suppress(DriverError):
            self._transact(f"STOP {min(2.0, self.limits.ramp_max_s):.3f}")

    # ---- transactions

    def _transact(self, text: str) -> str:
        lines = self.lines
        with self._io:
            lines.clear()
            lines.link.discard_input()
            lines.link.write(encode_line(text) + b"\n")
            try:
                reply = decode_line(lines.read_line(self.timeout_s)).decode("ascii", "replace")
            except DeviceTimeout:
                raise DeviceTimeout(DEVICE, f"no reply to {text!r} within {self.timeout_s:g} s") from None
        flag, _, data = reply.partition(" ")
        if flag == "ER":
            raise DeviceFault(DEVICE, f"{text!r} rejected: {data}", field="reply", value=data)
        if flag != "OK":
            raise FrameError(DEVICE, f"malformed reply {reply!r} to {text!r}")
        return data

    def _query(self, text: str) -> str:
        return with_retries(lambda: self._transact(text), self.retries)

    # ---- queries

    def identify(self) -> str:
        return self._query("IDN?")

    def status(self) -> ShakerStatus:
        data = self._query("STAT?")
        try:
            state, mode, level, alarm = data.split()
            value = float(level)
        except ValueError as exc:
            raise FrameError(DEVICE, f"malformed status {data!r}") from exc
        if state not in STATES or mode not in MODES:
            raise FrameError(DEVICE, f"unknown state or mode in {data!r}")
        return ShakerStatus(state, mode, value, None if alarm == "--" else alarm)

    def check(self) -> ShakerStatus:
        """The status; DeviceFault if an alarm is latched (the drive is already off)."""
        st = self.status()
        if st.alarm is not None:
            raise DeviceFault(DEVICE, f"alarm {st.alarm}: the drive stopped", field="alarm", value=st.alarm)
        return st

    # ---- settings and motion

    def set_sine(self, freq_hz: float, amp_g: float) -> None:
        check_sine(self.limits, freq_hz, amp_g)
        self._query(f"SINE {freq_hz:.4f} {amp_g:.4f}")

    def set_random(self, rms_g: float, lo_hz: float, hi_hz: float) -> None:
        check_random(self.limits, rms_g, lo_hz, hi_hz)
        self._query(f"RAND {rms_g:.4f} {lo_hz:.4f} {hi_hz:.4f}")

    def start(self, ramp_s: float) -> None:
        """Drive up to the set test over ramp_s (not retried: ask status() after a timeout)."""
        check_ramp(self.limits, ramp_s)
        self._transact(f"START {ramp_s:.3f}")

    def stop(self, ramp_s: float) -> None:
        """Ramp down and open the loop (idempotent, retried)."""
        check_ramp(self.limits, ramp_s)
        self._query(f"STOP {ramp_s:.3f}")

    def abort(self) -> None:
        """Drive off at once (idempotent, retried)."""
        self._query("ABORT")

    def safe_stop(self) -> None:
        """The station's safe stop: ramp down over the shortest allowed ramp, up to 2 s."""
        self.stop(min(2.0, self.limits.ramp_max_s))

    def emergency_stop(self) -> None:
        """The station's emergency stop: drive off at once."""
        self.abort()

    def clear_alarm(self) -> None:
        self._query("ALARM:CLR")


def open_shaker(section: ShakerSection, clock: Clock) -> ShakerController:
    if section.port is None:
        raise DriverError(DEVICE, "no serial port configured for [shaker]")
    del clock  # the controller keeps its own time
    shaker = ShakerController(section.port, section, baud=section.baud).open()
    try:
        shaker.identify()
    except DriverError:
        shaker.close()
        raise
    return shaker


def emulate_shaker(section: ShakerSection, world) -> object:
    from devices.shaker.emulator import ShakerEmulator

    emulator = ShakerEmulator(world, section)
    emulator.start()
    return emulator


DEVICE_KIND = DeviceKind("shaker", ShakerSection, open_shaker, emulate_shaker)
