"""Typed driver errors shared by every device driver.

Each error names the device and, where it applies, the field, the offending
value and what is allowed, so a message read in a log is enough to act on:

    LimitError: vibration table servo: freq_hz = 12.0 out of range (allowed 0.1 .. 10 Hz)
"""

from __future__ import annotations

from typing import Any

from station.errors import DeviceError, TransientFault


class DriverError(DeviceError):
    """Base of all driver errors: `device` plus an optional field/value/allowed triple."""

    def __init__(
        self,
        device: str,
        message: str,
        *,
        field: str | None = None,
        value: Any = None,
        allowed: str | None = None,
    ) -> None:
        self.device = device
        self.field = field
        self.value = value
        self.allowed = allowed
        parts = [f"{device}: "]
        if field is not None:
            parts.append(f"{field} = {value!r}: ")
        parts.append(message)
        if allowed is not None:
            parts.append(f" (allowed {allowed})")
        super().__init__("".join(parts))


class DeviceTimeout(DriverError):  # noqa: N818 (names fixed by the project)
    """The device did not answer within a bounded time."""


class FrameError(DriverError, TransientFault):
    """A reply was malformed (bad framing, length, or unexpected content): transient, the point may be repeated."""


class ChecksumError(FrameError):
    """A reply's checksum or CRC did not match."""


class ReplyLost(DeviceTimeout, TransientFault):
    """A command's reply never arrived (dropped or garbled beyond recognition) on a link that otherwise works:
    transient where the command can be undone (the counter's ARM: abort, then arm again)."""


class LostSamples(DriverError, TransientFault):  # noqa: N818
    """A stream lost samples (a FIFO overflow, a host stall): transient, the stretch or point may be repeated."""


class Disconnected(DriverError):  # noqa: N818
    """The transport went away (port closed, cable pulled, bus gone)."""


class DeviceFault(DriverError):  # noqa: N818
    """The device reported a fault of its own (error code, alarm bit, EMCY)."""


class BusOff(Disconnected):
    """A fieldbus stopped carrying traffic (CAN bus-off or equivalent)."""


class InterlockError(DriverError):
    """An interlock forbids the request (device not enabled, e-stop active, ...)."""


class LimitError(DriverError):
    """A requested value lies outside the configured limits; nothing was sent."""
