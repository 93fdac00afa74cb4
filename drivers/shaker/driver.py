"""Electrodynamic shaker: the vibration controller of a slip table (sine and random control), ASCII over RS-232.

The station's second kind of table (seed 002 §4: an electrodynamic bench of 1-2500 Hz, sine
thrust 50 kN, random thrust 50 kN RMS), beside the crank-driven table of 0.1-10 Hz.

Command  `<text>*<crc>\\n`     Reply  `<OK|ER> <data>*<crc>\\r\\n`
crc: CRC-16/CCITT-FALSE (drivers.serial_port.crc16) of the text before `*`, four upper-case
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
from dataclasses import dataclass

from drivers.errors import DeviceFault, DeviceTimeout, DriverError, FrameError
from drivers.serial_port import SerialDevice, with_retries
from drivers.shaker.envelope import ShakerSection, check_ramp, check_random, check_sine
from drivers.shaker.protocol import DEVICE, MODES, STATES, decode_line, encode_line
from station.clock import Clock


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
    """Driver of the vibration controller; `limits` is the table's envelope (its config section).

    The controller keeps its own time; `clock`, the station clock, only times the replies (its link clock).
    """

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        limits: ShakerSection,
        *,
        baud: int = 115_200,
        timeout_s: float = 0.5,
        retries: int = 2,
        clock: Clock | None = None,
    ) -> None:
        super().__init__(port, baud, clock=clock)
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
