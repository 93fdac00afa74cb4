"""pyserial's `Serial` for `sim://<name>` URLs: a port on a drivers.sim_serial line.

The port's timeout counts station seconds of the emulator's clock; everything
else is in drivers.sim_serial.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import urlsplit

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, to_bytes

from drivers import sim_serial


class Serial(SerialBase):
    """A serial port on a simulated line (pyserial's interface; modem lines are not modelled)."""

    is_open: bool

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._line: sim_serial.SimLine | None = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        parts = urlsplit(self._port)
        if parts.scheme != sim_serial.SCHEME or parts.path or parts.query or parts.fragment:
            raise SerialException(f"expected {sim_serial.SCHEME}://<name>, got {self._port!r}")
        line = sim_serial.line(parts.netloc)
        self._reconfigure_port()
        line.acquire(bool(self._exclusive))
        self._line = line
        self.is_open = True

    def close(self) -> None:
        if self.is_open and self._line is not None:
            self.is_open = False
            self._line.release(bool(self._exclusive))
        super().close()

    def _reconfigure_port(self) -> None:
        if not isinstance(self._baudrate, int) or not 0 < self._baudrate < 2**32:
            raise ValueError(f"invalid baudrate: {self._baudrate!r}")

    def _open_line(self) -> sim_serial.SimLine:
        if not self.is_open or self._line is None:
            raise PortNotOpenError()
        return self._line

    @property
    def in_waiting(self) -> int:
        return self._open_line().in_waiting()

    def read(self, size: int = 1) -> bytes:
        line = self._open_line()
        if size <= 0:
            return b""
        return line.read(size, self._timeout, lambda: self.is_open)

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        line = self._open_line()
        return line.read_until(expected, size if size is not None else 2**31, self._timeout, lambda: self.is_open)

    def write(self, data: Any) -> int:
        payload = to_bytes(data)
        self._open_line().write(payload)
        return len(payload)

    def reset_input_buffer(self) -> None:
        self._open_line().discard_input()

    def reset_output_buffer(self) -> None:
        self._open_line()  # a write reaches the emulator at once: nothing waits for the line

    @property
    def out_waiting(self) -> int:
        self._open_line()
        return 0

    def _update_break_state(self) -> None:
        """No break condition on a simulated line."""

    def _update_rts_state(self) -> None:
        """No modem lines on a simulated line."""

    def _update_dtr_state(self) -> None:
        """No modem lines on a simulated line."""
