"""The gradiometer as a device a station may have: its [gradiometer] section, how it opens and how it is emulated."""

from __future__ import annotations

from typing import Any

from drivers.config import SerialSection
from drivers.errors import DeviceFault
from drivers.gradiometer.driver import Gradiometer
from drivers.gradiometer.protocol import DEVICE
from drivers.registry import DeviceKind
from station.clock import Clock
from station.validation import in_range, settings, spec


@settings
class GradiometerSection(SerialSection):
    """`[gradiometer]` of a station file."""

    address: int = spec(in_range(1, 99))
    resolution_arcsec: float = spec(in_range(0.0, 10.0, lo_open=True))
    range_arcsec: float = spec(in_range(0.0, 36_000.0, lo_open=True))


def open_gradiometer(section: GradiometerSection, clock: Clock) -> Gradiometer:
    """Open the port and check that the instrument answering is the one configured."""
    grad = Gradiometer(section.port or "", baud=section.baud, address=section.address, clock=clock).open()
    try:
        ident = grad.identify()
        for name in ("resolution_arcsec", "range_arcsec"):
            got, want = getattr(ident, name), getattr(section, name)
            if abs(got - want) > 1e-9 * max(abs(want), 1.0):
                raise DeviceFault(DEVICE, f"instrument {ident.model} {ident.serial} disagrees with [gradiometer]",
                                  field=name, value=got, allowed=f"{want:g} as configured")  # fmt: skip
    except BaseException:
        grad.close()
        raise
    return grad


def emulate_gradiometer(section: GradiometerSection, world: Any) -> Any:
    """The emulator on the simulated world (a GradiometerEmulator, started), configured as the section says."""
    from drivers.gradiometer.emulator import GradiometerEmulator

    emu = GradiometerEmulator(
        world, baud=section.baud, address=section.address,
        resolution_arcsec=section.resolution_arcsec, range_arcsec=section.range_arcsec,
    )  # fmt: skip
    return world.attach(emu)


DEVICE_KIND = DeviceKind("gradiometer", GradiometerSection, open_gradiometer, emulate_gradiometer)
