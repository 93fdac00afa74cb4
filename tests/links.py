"""The links every device test runs on: today's (a pty served by the emulator's thread, python-can's
`virtual` bus with its Notifier threads) and the synchronous ones of the deterministic station (a
`sim://` line, the `station_sim` CAN interface). tests/conftest.py parametrises `transport` and
`interface` over them."""

from __future__ import annotations

from drivers import sim_can
from drivers.pty_link import PtyEmulator

TRANSPORTS = ("pty", "sim")
CAN_INTERFACES = ("virtual", sim_can.INTERFACE)


def serve(emu: PtyEmulator, transport: str) -> str:
    """Start the emulator on `transport`; the port its driver opens."""
    return emu.start() if transport == "pty" else emu.start_sim()
